# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
# ---

# # Which energy does what (the paper's Fig. 11)
#
# Bending along the fibre (Db1), across it (Db2) and fibre tension (sigma1) switched between 0 and 1,
# on the 4-harness satin; cross-sections along a warp yarn's centre, side by side.

# +
import os
from pathlib import Path

import numpy as np
from mpi4py import MPI

from textile_fenicsx.correction.correct import CorrectionOptions, corrected_textile
from textile_fenicsx.model.weaves import build
from textile_fenicsx.plate.mesh.midsurface import mid_surfaces
from textile_fenicsx.plate.mesh.projected import MeshOptions, projected_mesh
from textile_fenicsx.plate.solver import PlateParameters, solve
from textile_fenicsx.plot.plotting import yarn_colours

comm = MPI.COMM_WORLD
seed = float(os.environ.get("TEXTILE_FENICSX_SEED", "0.5"))
out = Path(os.environ.get("TEXTILE_FENICSX_OUT", "output/parameter_study"))
say = print if comm.rank == 0 else (lambda *_: None)
textile = build("crowfoot_satin", spacing=2.8, width=2.5, height=0.35, thickness=0.7)
ms = mid_surfaces(projected_mesh(textile, MeshOptions(seed), comm))
correction = CorrectionOptions(section_points=48)
# -

# Each case keeps a little of every stiffness that is "off" (1e-3) so the plates stay determined.

# +
cases = {"Db1=1 Db2=1 sigma1=1": (1, 1, 1), "Db1=1 Db2=0 sigma1=0": (1, 0, 0),
         "Db1=0 Db2=1 sigma1=0": (0, 1, 0), "Db1=0 Db2=0 sigma1=1": (0, 0, 1)}
results = {}
for label, (b1, b2, s1) in cases.items():
    p = PlateParameters(Db1=max(b1, 1e-3), Db2=max(b2, 1e-3), sigma1=max(s1, 1e-3))
    sol = solve(ms, p)
    results[label] = corrected_textile(textile, sol.w, correction.station_spacing(seed), correction.section_points)
    say(f"{label}: {sol.iterations} iterations, max |w| "
        f"{comm.allreduce(max(float(np.abs(w.x.array).max(initial=0)) for w in sol.w), op=MPI.MAX):.3f} mm")
# -

if comm.rank == 0:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    y0 = float(np.mean(textile.yarns[0].nodes[:-1, 1]))
    x = np.linspace(0, textile.cell.lx, 600)
    xy = np.column_stack((x, np.full_like(x, y0)))
    fig, axes = plt.subplots(len(results) + 1, 1, figsize=(10, 2.1 * (len(results) + 1) + 0.3), sharex=True,
                             sharey=True)
    colours, shown = yarn_colours(len(textile.yarns)), {}
    for ax, (label, t) in zip(axes, [("idealised", textile)] + list(results.items())):
        bot, top = t.columns(xy).envelope(len(t.yarns))
        for i in range(len(t.yarns)):
            if not np.all(np.isnan(bot[:, i])):
                shown[i] = ax.fill_between(x, bot[:, i], top[:, i], where=~np.isnan(bot[:, i]), alpha=0.75,
                                           linewidth=0, color=colours[i])
        ax.set_title(label, fontsize=9)
        ax.set_ylabel("z [mm]")
    axes[-1].set_xlabel("x [mm] along warp 0")
    # the yarns in the colours of the run's other figures, named below
    fig.legend([shown[i] for i in sorted(shown)], [textile.yarns[i].name for i in sorted(shown)], loc="lower center",
               ncol=len(shown), fontsize=9, frameon=False)
    fig.tight_layout(rect=(0, 0.3 / fig.get_figheight(), 1, 1))
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "parameter_study.png", dpi=110)
    say(f"parameter_study: wrote {out}/parameter_study.png")
