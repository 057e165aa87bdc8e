# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
# ---

# # Edge effects: a coupon cut out of the fabric
#
# A unit cell describes the inside of a large fabric: every repeat has the same neighbours. A test
# coupon has edges, where the yarns are cut and nothing holds their ends. Here the 4-harness satin is
# solved twice as a 3 x 3 coupon: periodic (the fabric's inside, equal to the unit cell in every
# repeat) and with free edges (`tile(..., free_edges=True)`, `--repeat 3 3 --free-edges` on the
# command line). The difference of the corrected fabrics' top surfaces shows how far in the edges
# reach.
#
# Run with `mpirun -n 2` as well; `TEXTILE_FENICSX_SEED` (default 0.5 mm) and
# `TEXTILE_FENICSX_REPEATS` (default 3) set the mesh and the coupon size.

# +
import json
import os
from pathlib import Path

import numpy as np
from mpi4py import MPI

import textile_fenicsx as tfx
from textile_fenicsx.correction.correct import CorrectionOptions

comm = MPI.COMM_WORLD
seed = float(os.environ.get("TEXTILE_FENICSX_SEED", "0.5"))
n = int(os.environ.get("TEXTILE_FENICSX_REPEATS", "3"))
out = Path(os.environ.get("TEXTILE_FENICSX_OUT", "output/coupon_edges"))
say = print if comm.rank == 0 else (lambda *_: None)
unit = tfx.build("crowfoot_satin", spacing=2.8, width=2.5, height=0.35, thickness=0.7)
# -

# ## The two coupons
#
# Both have the same yarn geometry inside the box; the free one's yarns are not periodic and end a
# period beyond each side. Both are meshed as the unit cell's mesh repeated.

# +
corrected = {}
for label, free in (("periodic", False), ("free edges", True)):
    result = tfx.solve(unit, seed=seed, repeat=(n, n), free_edges=free, comm=comm,
                       correction=CorrectionOptions(section_points=48))
    s = result.summary()
    say(f"{label}: {len(result.textile.yarns)} yarns, {s['dofs']} dofs, {result.solution.iterations} contact "
        f"iterations, max |w| {s['max_abs_w']:.3f} mm")
    corrected[label] = result.corrected
# -

# ## How far the edges reach
#
# The top surface of each corrected coupon on a grid of vertical rays; per repeat, the largest
# difference. The centre repeat of the free coupon should look like the periodic fabric.

# +
if comm.rank == 0:
    x0, x1, y0, y1 = corrected["periodic"].cell.bounds
    m = 60 * n
    xs = np.linspace(x0, x1, m + 1)[:-1] + (x1 - x0) / (2 * m)
    ys = np.linspace(y0, y1, m + 1)[:-1] + (y1 - y0) / (2 * m)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    xy = np.column_stack((X.ravel(), Y.ravel()))
    tops = {}
    for label, t in corrected.items():
        _, top = t.columns(xy).envelope(len(t.yarns))
        tops[label] = np.fmax.reduce(top, axis=1).reshape(m, m)  # NaN in the gaps between yarns
    diff = tops["free edges"] - tops["periodic"]
    per_repeat = np.nanmax(np.abs(diff).reshape(n, m // n, n, m // n), axis=(1, 3))
    say("largest |top(free) - top(periodic)| per repeat [mm] (rows: x, columns: y):")
    say(np.array2string(per_repeat, precision=3))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6))
    lim = float(np.nanmax(np.abs(diff)))
    im = ax.imshow(diff.T, origin="lower", extent=(x0, x1, y0, y1), cmap="RdBu_r", vmin=-lim, vmax=lim)
    for k in range(1, n):
        ax.axvline(x0 + k * (x1 - x0) / n, color="k", lw=0.5)
        ax.axhline(y0 + k * (y1 - y0) / n, color="k", lw=0.5)
    fig.colorbar(im, ax=ax, label="top surface, free edges minus periodic [mm]")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title(f"satin {n} x {n} coupon, seed {seed:g} mm: free edges minus periodic", fontsize=10)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "edge_effect.png", dpi=110)
    (out / "edge_effect.json").write_text(json.dumps(
        {"seed_mm": seed, "repeats": n, "max_abs_top_difference_per_repeat_mm": per_repeat.tolist()}, indent=1))
    say(f"coupon_edges: wrote {out}/edge_effect.png and edge_effect.json")
# -
