# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
# ---

# # Mesh convergence on the 4-harness satin (the paper's Fig. 10)
#
# The same satin at seeds 2.0, 1.0, 0.5, 0.35 and 0.25 mm: nodes, time and how much the corrected
# geometry still changes between successive seeds, measured as the RMS over the cell of the
# difference of each yarn's corrected height z = z0 + w at its centreline stations.

# +
import os
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

from textile_fenicsx.model.weaves import build
from textile_fenicsx.pipeline.stages import Settings, run
from textile_fenicsx.plate.mesh.projected import MeshOptions
from textile_fenicsx.plate.point_values import evaluate

comm = MPI.COMM_WORLD
seeds = [float(s) for s in os.environ.get("TEXTILE_FENICSX_SEEDS", "2.0 1.0 0.5 0.35 0.25").split()]
out = Path(os.environ.get("TEXTILE_FENICSX_OUT", "output/mesh_convergence"))
say = print if comm.rank == 0 else (lambda *_: None)
textile = build("crowfoot_satin", spacing=2.8, width=2.5, height=0.35, thickness=0.7)
# -

# Stations along every yarn's centreline, away from its ends: where each solution is compared.

stations = []
for y in textile.yarns:
    pos, _ = y.centreline(y.stations(0.1)[1:-1])
    stations.append(pos[:, :2])


# +
def centre_heights(result):
    heights = []
    for y, w, xy in zip(result.midsurfaces.yarns, result.solution.w, stations):
        z = w.copy()
        z.x.array[:] += y.z0.x.array
        heights.append(evaluate(z, xy))
    return np.concatenate(heights)


rows, previous = [], None
for seed in seeds:
    start = time.perf_counter()
    # remesh=0: each run at its own seed (by default a run that overlaps is done again finer)
    result = run(textile, Settings(MeshOptions(seed), remesh=0), comm=comm)
    z = centre_heights(result)
    s = result.summary()
    change = float(np.sqrt(np.nanmean((z - previous) ** 2))) if previous is not None else float("nan")
    rows.append((seed, s["cells"], s["dofs"], s["iterations"], time.perf_counter() - start, change))
    say(f"seed {seed:5.2f} mm: {s['cells']:6d} cells, {s['dofs']:7d} dofs, {s['iterations']:3d} iterations, "
        f"{rows[-1][4]:6.2f} s, RMS change of centre heights vs previous seed {change:.2e} mm")
    previous = z
# -

# A table and a plot:

if comm.rank == 0:
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "mesh_convergence.csv", "w") as f:
        f.write("seed_mm,cells,dofs,iterations,time_s,rms_change_mm\n")
        for r in rows:
            f.write(",".join(str(v) for v in r) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    a.loglog([r[2] for r in rows], [r[4] for r in rows], "o-")
    a.set_xlabel("dofs")
    a.set_ylabel("time [s]")
    b.loglog([r[0] for r in rows[1:]], [r[5] for r in rows[1:]], "s-")
    b.set_xlabel("seed [mm]")
    b.set_ylabel("RMS change vs previous seed [mm]")
    fig.tight_layout()
    fig.savefig(out / "mesh_convergence.png", dpi=110)
    say(f"mesh_convergence: wrote {out}/mesh_convergence.csv and .png")
