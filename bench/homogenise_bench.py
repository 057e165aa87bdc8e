"""Homogenisation on a synthetic cell of the 4-harness satin's size: what decides the default mesh.

The cell is 11.2 x 11.2 x 1 mm with 8 yarns (4 along x in the lower half, 4 along y in the upper
half, 2.4 mm wide on a 2.8 mm pitch, 0.35 mm thick, crimped by +-0.1 mm along their length), T300
fibres at Vf 0.6 in epoxy (yarn E11 139 GPa, E22 9.4 GPa against the matrix's 3.35 GPa; the
contrast of the real cell), phases and fibre directions from the cell midpoints of a structured
box mesh (tetrahedra by default, P2; or hexahedra, Q2), solved with the default p-multigrid
(cellproblem.CG_PMG). For each size and number of ranks, a fresh
process runs homogenise() after a warm-up that fills the form cache, and reports the dofs, the
CG iterations and seconds of every load case, the setup times, homogenise()'s wall time
("total") and CPU time (the largest rank's: on a loaded machine, near what the wall time would be
on a quiet one, serially), the peak memory (the sum of the ranks' peak resident sizes) and the
load average when the case ended.

    python3 bench/homogenise_bench.py [--sizes 100k 300k 600k] [--ranks 1 2] [--cell tetrahedron]
                                      [--rtol 1e-5] [--options '{"mg_coarse_pc_gamg_threshold": 0.02}'] [--out f.json]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# boxes (nx, ny, nz) whose P2/Q2 node lattices (2n + 1 per side) give about these many dofs
SIZES = {"tiny": (6, 6, 2), "100k": (34, 34, 3), "300k": (52, 52, 4), "600k": (66, 66, 5), "1m": (80, 80, 6)}
PITCH, WIDTH, THICK, CRIMP = 2.8, 2.4, 0.35, 0.1


def synthetic_cell(comm, n, cell: str):
    """mesh, cell tags (0 matrix, 1-4 yarns along x, 5-8 along y), DG0 directions and Vf."""
    import numpy as np

    import dolfinx

    kind = dolfinx.mesh.CellType.tetrahedron if cell == "tetrahedron" else dolfinx.mesh.CellType.hexahedron
    msh = dolfinx.mesh.create_box(comm, [[0.0, 0.0, 0.0], [4 * PITCH, 4 * PITCH, 1.0]], list(n), kind)
    imap = msh.topology.index_map(3)
    cells = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
    x, y, z = dolfinx.mesh.compute_midpoints(msh, 3, cells).T
    k = 2 * np.pi / (2 * PITCH)
    tags = np.zeros(len(cells), np.int32)
    a = np.tile([1.0, 0.0, 0.0], (len(cells), 1))
    # along x, lower half: centre line z = 0.275 + crimp sin(k x + j pi)
    j = np.floor(y / PITCH)
    zc = 0.275 + CRIMP * np.sin(k * x + j * np.pi)
    warp = (np.abs(y - (j + 0.5) * PITCH) < WIDTH / 2) & (np.abs(z - zc) < THICK / 2)
    tags[warp] = 1 + j[warp]
    a[warp] = np.stack([np.ones(warp.sum()), 0 * x[warp], CRIMP * k * np.cos(k * x[warp] + j[warp] * np.pi)], 1)
    i = np.floor(x / PITCH)
    zc = 0.725 + CRIMP * np.sin(k * y + i * np.pi)
    weft = (np.abs(x - (i + 0.5) * PITCH) < WIDTH / 2) & (np.abs(z - zc) < THICK / 2) & ~warp
    tags[weft] = 5 + i[weft]
    a[weft] = np.stack([0 * y[weft], np.ones(weft.sum()), CRIMP * k * np.cos(k * y[weft] + i[weft] * np.pi)], 1)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    W3 = dolfinx.fem.functionspace(msh, ("DG", 0, (3,)))
    W = dolfinx.fem.functionspace(msh, ("DG", 0))
    direction, vf = dolfinx.fem.Function(W3, name="direction"), dolfinx.fem.Function(W, name="yarn_vf")
    direction.x.array.reshape(-1, 3)[W3.dofmap.list[:, 0]] = a
    vf.x.array[W.dofmap.list[:, 0]] = np.where(tags > 0, 0.6, 0.0)
    return msh, dolfinx.mesh.meshtags(msh, 3, cells, tags), direction, vf


def one(args) -> None:
    """The child: one case on the ranks mpirun gave it; prints RESULT <json> on rank 0."""
    from mpi4py import MPI

    from textile_fenicsx.homogenisation import HomogeniseOptions, homogenise
    from textile_fenicsx.homogenisation.cellproblem import default_solver

    comm = MPI.COMM_WORLD
    solver = dict(default_solver(2), ksp_rtol=args.rtol, **json.loads(args.options))
    options = HomogeniseOptions(elasticity_solver=solver, conduction_solver=dict(solver))
    homogenise(*synthetic_cell(comm, SIZES["tiny"], args.cell), "t300", "epoxy", options)  # fills the form cache
    t0 = time.perf_counter()
    cell = synthetic_cell(comm, SIZES[args.one], args.cell)
    t_mesh = time.perf_counter() - t0
    c0 = time.process_time()
    r = homogenise(*cell, "t300", "epoxy", options)
    cpu = comm.allreduce(time.process_time() - c0, op=MPI.MAX)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0
    peaks = comm.gather(peak, root=0)
    if comm.rank == 0:
        record = {"size": args.one, "cell": args.cell, "ranks": comm.size, "dofs": r.dofs, "iterations": r.iterations,
                  "seconds": {**r.seconds, "mesh": t_mesh, "wall": wall, "cpu": cpu}, "peak_bytes": sum(peaks),
                  "peak_bytes_per_rank": max(peaks), "constants": r.constants, "C": r.C.tolist(),
                  "yarn_fraction": r.yarn_fraction, "solver": solver, "load_average": os.getloadavg()}
        print("RESULT " + json.dumps(record), flush=True)


def table(records) -> str:
    lines = [f"{'size':>5} {'cell':>11} {'ranks':>5} {'dofs':>8} {'elastic its (6 cases)':>26} {'s/case':>7} "
             f"{'assembly':>8} {'PC':>6} {'thermal':>7} {'total':>6} {'cpu':>6} {'peak GB':>7} {'B/dof':>6} "
             f"{'load':>5}"]
    for r in records:
        s = r["seconds"]
        its = " ".join(str(i) for i in r["iterations"]["elasticity"])
        thermal = s.get("conduction_assembly", 0) + s.get("conduction_preconditioner", 0) + sum(
            s.get("conduction_solves", []))
        lines.append(f"{r['size']:>5} {r['cell']:>11} {r['ranks']:>5} {r['dofs']['elasticity']:>8} {its:>26} "
                     f"{sum(s['elasticity_solves']) / 6:>7.2f} {s['elasticity_assembly']:>8.2f} "
                     f"{s['elasticity_preconditioner']:>6.2f} {thermal:>7.2f} {s['total']:>6.1f} {s['cpu']:>6.1f} "
                     f"{r['peak_bytes'] / 1e9:>7.2f} {r['peak_bytes'] / r['dofs']['elasticity']:>6.0f} "
                     f"{r['load_average'][0]:>5.1f}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", nargs="+", default=["100k", "300k", "600k"], choices=list(SIZES))
    parser.add_argument("--ranks", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--cell", default="tetrahedron", choices=["tetrahedron", "hexahedron"])
    parser.add_argument("--rtol", type=float, default=1e-5, help="CG's relative residual (both problems)")
    parser.add_argument("--options", default="{}", help="more PETSc options (JSON), over cellproblem.CG_PMG's: "
                        "the coarse level's GAMG under mg_coarse_")
    parser.add_argument("--out", type=Path, help="write the records as JSON here")
    parser.add_argument("--one", choices=list(SIZES), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        return one(args)
    env = dict(os.environ, PYTHONPATH=f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    records = []
    for size in args.sizes:
        for ranks in args.ranks:
            command = ([] if ranks == 1 else ["mpirun", "-n", str(ranks)]) + [
                sys.executable, __file__, "--one", size, "--cell", args.cell, "--rtol", str(args.rtol),
                "--options", args.options]
            done = subprocess.run(command, env=env, capture_output=True, text=True)
            lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
            if done.returncode != 0 or not lines:
                print(done.stdout[-2000:], done.stderr[-4000:], file=sys.stderr)
                raise SystemExit(f"{size} on {ranks} rank(s) failed (exit {done.returncode})")
            records.append(json.loads(lines[-1][len("RESULT "):]))
            print(table(records[-1:]).splitlines()[-1], flush=True)
    print(table(records))
    if args.out:
        args.out.write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
