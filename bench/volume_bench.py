"""The volume stage's bench (make bench-volume): volume-mesh + homogenise + permeability of the corrected satin4.

The 4-harness satin (reference/models/satin4.tg3) is corrected at seed 0.5 by the default command
(and, for the tet mesh, with the tet mesher's gap held: `solve --min-gap`), then, as a user runs
them, each in a fresh process, serially and on 2 ranks:

    textile-fenicsx volume-mesh corrected.tg3 --kind KIND --size H --out DIR
    textile-fenicsx homogenise DIR/volume.xdmf --out DIR
    textile-fenicsx permeability DIR/volume.xdmf --fibre-radius 0.0035 --out DIR/flow

It reports per command the wall time, the peak resident memory of the largest process, the mesh's
elements, the cell problems' unknowns and CG iterations, and writes output/volume_bench.json:

    python3 bench/volume_bench.py [--kinds voxel tet] [--ranks 1 2] [--sizes voxel=0.2 tet=0.35]
                                  [--degree 2]

(the sizes by default voxel 0.2 mm, the voxels' default until issue 72, whose rows docs/volume.md
compares, and the tet's default 0.35 mm, volume/box.py DEFAULT_SIZE; the voxels' default now is per
axis, from the yarns: on the corrected satin 53 x 53 x 21 voxels, 1.42 M unknowns).

Several sizes per kind (`--sizes voxel=0.2,0.1 tet=0.35,0.25`) make a refinement study: the table then
gives each engineering constant's change from the size before, and voxel against tet at the finest.
That last line compares two models: the voxel mesh is of the default corrected satin (its own
thickness), the tet mesh of the one solved with the tet's gap (thicker, in a box padded by half the
gap). To compare the discretisations alone, mesh the tet's model as voxels in the tet's box
(`volume-mesh ... --kind voxel --z-range` with mesh_report.json's box_mm): docs/volume.md, "Refinement,
and voxel against tet".
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "reference" / "models" / "satin4.tg3"


# Runs a command and prints, on its last line, the peak resident memory of its largest process [kB]
# and the CPU seconds of all its processes (on a shared machine the CPU time is the steadier measure)
_PEAK = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
         "u = resource.getrusage(resource.RUSAGE_CHILDREN); "
         "print(u.ru_maxrss, u.ru_utime + u.ru_stime, file=sys.stderr); sys.exit(r.returncode)")


def timed(command: list[str], ranks: int = 1) -> dict:
    """Run a command (under mpirun -n ranks if > 1) in a fresh process: its wall time and the peak
    resident memory of its largest process [GB]; raises if it fails."""
    mpi = ["mpirun", "-n", str(ranks)] if ranks > 1 else []
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _PEAK, *mpi, sys.executable, "-m", "textile_fenicsx", *command],
                          capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    peak, cpu = map(float, proc.stderr.strip().splitlines()[-1].split())
    return {"seconds": wall, "cpu_seconds": cpu, "peak_gb": peak / 1e6, "stdout": proc.stdout.strip()}


def corrected(folder: Path, gap: bool) -> Path:
    """satin4 corrected at seed 0.5 by the default command (with the tet mesher's gap if asked)."""
    extra = ["--volume-mesh", "tet", "--volume-size", "1.0"] if gap else []  # the gap, and a quick mesh
    timed(["solve", str(MODEL), "--seed", "0.5", "--no-figures", *extra, "--out", str(folder)])
    return folder / "corrected.tg3"


def permeability(folder: Path, ranks: int) -> dict:
    """`permeability` on the volume mesh in folder (Gebart's yarns, carbon's 3.5 um fibres): its wall
    time, peak memory, unknowns, iterations a load case, solver and K's diagonal [m^2]."""
    run = timed(["permeability", str(folder / "volume.xdmf"), "--fibre-radius", "0.0035", "--out",
                 str(folder / "flow")], ranks)
    doc = json.loads((folder / "flow" / "permeability.json").read_text())
    return {"seconds": run["seconds"], "cpu_seconds": run["cpu_seconds"], "peak_gb": run["peak_gb"],
            "dofs": doc["dofs"], "iterations": doc["options"]["iterations"], "solver": doc["options"]["solver"],
            "stages_s": doc["seconds"], "K_m2": [doc["K_m2"][i][i] for i in range(3)], "vf": doc["vf"]}


def case(model: Path, kind: str, size: float, ranks: int, folder: Path, degree: int = 2, flow: bool = True) -> dict:
    mesh = timed(["volume-mesh", str(model), "--kind", kind, "--size", str(size), "--out", str(folder)], ranks)
    homog = timed(["homogenise", str(folder / "volume.xdmf"), "--degree", str(degree), "--out", str(folder)], ranks)
    report = json.loads((folder / "mesh_report.json").read_text())
    stiffness = json.loads((folder / "stiffness.json").read_text())
    return {"permeability": permeability(folder, ranks) if flow else None,
            "kind": kind, "size": size, "ranks": ranks, "degree": degree, "elements": report["elements"],
            "dofs": stiffness["dofs"], "iterations": stiffness["iterations"],
            "mesh_s": mesh["seconds"], "mesh_cpu_s": mesh["cpu_seconds"], "mesh_peak_gb": mesh["peak_gb"],
            "homogenise_s": homog["seconds"], "homogenise_cpu_s": homog["cpu_seconds"],
            "homogenise_peak_gb": homog["peak_gb"],
            "total_s": mesh["seconds"] + homog["seconds"], "stages_s": stiffness["seconds"],
            "constants": stiffness["engineering_constants"], "vf": stiffness["fibre_volume_fraction"]}


def save(path: Path, records: list[dict]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"machine": os.uname().nodename, "load": os.getloadavg(), "records": records},
                               indent=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--kinds", nargs="+", default=["voxel", "tet"])
    parser.add_argument("--ranks", nargs="+", type=int, default=[1, 2])
    from textile_fenicsx.volume.box import DEFAULT_SIZE

    parser.add_argument("--sizes", nargs="+", default=["voxel=0.2", *(f"{k}={h}" for k, h in DEFAULT_SIZE.items())],
                        metavar="KIND=H[,H...]")
    parser.add_argument("--degree", type=int, default=2, choices=[1, 2])
    parser.add_argument("--no-permeability", action="store_true", help="leave out the permeability of each mesh")
    parser.add_argument("--out", type=Path, default=REPO / "output" / "volume_bench.json")
    args = parser.parse_args()
    sizes = {k: [float(h) for h in v.split(",")] for k, v in (s.split("=") for s in args.sizes)}
    records = []
    with tempfile.TemporaryDirectory(prefix="volume-bench-") as tmp:
        tmp = Path(tmp)
        models = {kind: corrected(tmp / f"solve_{kind}", kind == "tet") for kind in args.kinds}
        for kind in args.kinds:
            for size in sizes[kind]:
                for ranks in args.ranks:
                    print(f"volume bench: {kind} at {size} mm on {ranks} rank(s)", file=sys.stderr, flush=True)
                    records.append(case(models[kind], kind, size, ranks, tmp / f"{kind}_{size}_{ranks}", args.degree,
                                        not args.no_permeability))
                    save(args.out, records)  # each case as it ends: a later one may fail (memory)
                    r = records[-1]
                    print(f"volume bench: {r['elements']} elements, {r['dofs']['elasticity']} dofs, mesh "
                          f"{r['mesh_s']:.1f} s, homogenise {r['homogenise_s']:.1f} s", file=sys.stderr, flush=True)
    save(args.out, records)
    print(f"load average {os.getloadavg()[0]:.1f}; wall seconds (CPU seconds of all processes)")
    print("| kind | size mm | ranks | elements | dofs | CG its (6 cases) | volume-mesh | homogenise | total | "
          "peak GB (mesh / homogenise) | Ex MPa | Vf |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in records:
        peaks = f"{r['mesh_peak_gb']:.2f} / {r['homogenise_peak_gb']:.2f}"
        print(f"| {r['kind']} | {r['size']:g} | {r['ranks']} | {r['elements']} | {r['dofs']['elasticity']} | "
              f"{min(r['iterations']['elasticity'])}-{max(r['iterations']['elasticity'])} | {r['mesh_s']:.1f} s "
              f"({r['mesh_cpu_s']:.0f}) | {r['homogenise_s']:.1f} s ({r['homogenise_cpu_s']:.0f}) | "
              f"{r['total_s']:.1f} s | {peaks} | {r['constants']['Ex']:.0f} | "
              f"{r['vf']:.3f} |")
    print(changes(records))
    flows = [r for r in records if r["permeability"]]
    if flows:
        print("\npermeability (Stokes-Brinkman, Gebart's yarns, r = 3.5 um): wall seconds (CPU seconds)")
        print("| kind | size mm | ranks | dofs | solver | iterations (x, y, z) | assembly s | solves s | total | "
              "peak GB | Kxx m^2 | Kyy m^2 | Kzz m^2 |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in flows:
            f = r["permeability"]
            print(f"| {r['kind']} | {r['size']:g} | {r['ranks']} | {f['dofs']} | {f['solver'].split(',')[0]} | "
                  f"{'/'.join(map(str, f['iterations']))} | {f['stages_s']['assembly']:.1f} | "
                  f"{f['stages_s']['solves']:.1f} | {f['seconds']:.1f} s ({f['cpu_seconds']:.0f}) | "
                  f"{f['peak_gb']:.2f} | " + " | ".join(f"{k:.3e}" for k in f["K_m2"]) + " |")


def changes(records: list[dict], keys: tuple = ("Ex", "Ey", "Ez", "Gxy", "Gxz", "Gyz", "nuxy", "nuxz", "nuyz")) -> str:
    """Each constant's change from the size before (same kind, one rank), and voxel against tet at the
    finest sizes [%]."""
    lines = []
    serial = [r for r in records if r["ranks"] == min(x["ranks"] for x in records)]
    for kind in dict.fromkeys(r["kind"] for r in serial):
        runs = [r for r in serial if r["kind"] == kind]
        for a, b in zip(runs, runs[1:]):
            lines.append(f"{kind} {a['size']:g} -> {b['size']:g} mm: " + ", ".join(
                f"{k} {100 * (b['constants'][k] / a['constants'][k] - 1):+.2f} %" for k in keys))
    finest = {r["kind"]: r for r in serial}  # the last (finest) of each kind
    if {"voxel", "tet"} <= set(finest):
        v, t = finest["voxel"], finest["tet"]
        lines.append("voxel (default model) against tet (model solved with the gap, padded box): " + ", ".join(
            f"{k} {100 * (v['constants'][k] / t['constants'][k] - 1):+.2f} %" for k in keys))
    by_size = {}
    for r in records:
        by_size.setdefault((r["kind"], r["size"]), []).append(r)
    for (kind, size), rs in by_size.items():
        if len(rs) > 1:
            worst = max(abs(rs[0]["constants"][k] / r["constants"][k] - 1) for r in rs[1:] for k in keys)
            lines.append(f"{kind} {size:g} mm, {rs[0]['ranks']} against {', '.join(str(r['ranks']) for r in rs[1:])} "
                         f"ranks: constants within {worst:.1e}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
