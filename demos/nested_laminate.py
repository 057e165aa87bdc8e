# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
# ---

# # A 4-ply plain-weave laminate, nested and pressed
#
# Four plies of a plain weave (spacing 2 mm, yarns 1.8 x 0.3 mm, no fibre data: an intra-yarn fibre
# fraction of 0.65 is assumed) stacked in one periodic cell, each moved in the plane by a random
# offset (the plies of a real laminate are not in register). The usual solve lets them settle into
# each other (the spring that holds yarns together where they are apart draws each ply down as far
# as the yarns below let it), then the stack is pressed to Vf 0.55 with its yarns flattening (Van
# Wyk's law, K = 50 MPa, not fitted to a measured fabric). The same is done with one ply, and the
# thickness per ply compared.
#
# ## Mathematical formulation
#
# The plies are one textile: one projected mesh, one plate per yarn, one contact solve (docs/DESIGN.md
# 5, 5a). A ply moves only vertically: nesting here is the plies sinking into each other at their
# given offsets, not sliding into register.

# +
import os
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from mpi4py import MPI

import textile_fenicsx as tfx
from textile_fenicsx.model.plies import random_offsets, stack
from textile_fenicsx.pipeline.compaction import CompactionTarget
from textile_fenicsx.plot.plotting import yarn_colours

comm = MPI.COMM_WORLD
seed = float(os.environ.get("TEXTILE_FENICSX_SEED", "0.5"))
plies = int(os.environ.get("TEXTILE_FENICSX_PLIES", "4"))
vf = float(os.environ.get("TEXTILE_FENICSX_VF", "0.55"))
out = Path(os.environ.get("TEXTILE_FENICSX_OUT", "output/nested_laminate"))
tfx.show_progress()
start = time.perf_counter()
plain = tfx.build("plain")
offsets = random_offsets(plain, plies, seed=1)
laminate = stack(plain, plies, offsets)
# -

# Relaxed (nested) and pressed, the laminate and one ply:

target = CompactionTarget(50.0, vf=vf, steps=4)
relaxed = tfx.solve(laminate, seed=seed, comm=comm)
pressed = tfx.solve(laminate, seed=seed, comm=comm, compaction=target)
single = tfx.solve(plain, seed=seed, comm=comm, compaction=target)
for name, r in (("laminate, relaxed", relaxed), ("laminate, pressed", pressed), ("one ply, pressed", single)):
    verdict = r.verdict  # collective: every rank measures
    if comm.rank == 0:
        print(f"{name}: {r.summary_line()}")
        for failure in verdict["failures"]:  # e.g. at a coarse seed: the plates too coarse for the plies' contact
            print(f"  check: {failure['message']}")
if comm.rank == 0:
    per_ply = {name: r.metrics["after"]["thickness"] / r.textile.plies
               for name, r in (("relaxed", relaxed), ("pressed", pressed), ("one ply pressed", single))}
    print(f"offsets {offsets}; thickness per ply {per_ply} mm; pressure at Vf {vf}: laminate "
          f"{pressed.compaction.pressure[-1]:.3g} MPa, one ply {single.compaction.pressure[-1]:.3g} MPa")

# The laminate cut along the first ply's first warp: idealised stack, nested, pressed.

if comm.rank == 0:
    from textile_fenicsx.pipeline.outputs import cut_lines

    out.mkdir(parents=True, exist_ok=True)
    label, a, b = cut_lines(laminate)[0]
    a, b = np.asarray(a, float), np.asarray(b, float)
    t = np.linspace(0, 1, 800)
    xy = a + np.outer(t, b - a)
    colours = yarn_colours(plies)  # one colour per ply
    models = [("idealised stack", laminate), ("nested (relaxed)", relaxed.corrected),
              (f"pressed to Vf {vf:g}: {pressed.compaction.pressure[-1]:.3g} MPa"
               + ("" if pressed.verdict["passed"] else " (check FAILED)"), pressed.corrected)]
    fig, axes = plt.subplots(len(models), 1, figsize=(10, 2.4 * len(models)), sharex=True, sharey=True,
                             constrained_layout=True)
    s = t * np.linalg.norm(b - a)
    for ax, (title, textile) in zip(axes, models):
        bot, top = textile.columns(xy).envelope(len(textile.yarns))
        for i in range(len(textile.yarns)):
            if not np.all(np.isnan(bot[:, i])):
                ply = i // len(plain.yarns)
                ax.fill_between(s, bot[:, i], top[:, i], where=~np.isnan(bot[:, i]), color=colours[ply], alpha=0.8,
                                linewidth=0, label=f"ply {ply + 1}" if i % len(plain.yarns) == 0 else None)
        ax.set_title(title, fontsize=10)
        ax.set_ylabel("z [mm]")
    axes[0].legend(loc="upper right", fontsize=8, ncol=plies)
    axes[-1].set_xlabel(f"distance along the cut ({label}) [mm]")
    fig.savefig(out / "cross_sections.png", dpi=120)
    plt.close(fig)
    print(f"written to {out}/ in {time.perf_counter() - start:.0f} s")
