# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
# ---

# # The 4-harness satin pressed to the fibre volume fraction of a part
#
# TexGen's 4-harness satin with E-glass fibre data (`reference/models/satin4_fibres.tg3`: 1200 tex
# rovings of 17 um fibres at 2.55 g/cm^3 in 2.5 x 0.35 mm sections, an intra-yarn fibre fraction of
# 0.685). The usual solve gives the relaxed fabric, free of interpenetration and thicker than the
# idealised model. A part is pressed to Vf 0.5-0.6: here the relaxed fabric is pressed on to three
# targets, its yarns flattening by Van Wyk's law, and the platens' pressure is recorded. Then the
# permeability of the cell at each point of the last curve: how K falls as the fabric is pressed.
#
# ## Mathematical formulation
#
# Each yarn node has a bottom and a top height; the plate bends with their mean w and its thickness
# is t = t0 + dt. The bundle's energy per area is the work of Van Wyk's pressure,
#     W(t) = int_t^t0 p(s) ds,   p(t) = K phi0^3 ((t0 / t)^3 - 1),   phi = phi0 t0 / t,
# convex, added to the bending, tension and contact energy; the platens and the maximum packing
# (phi <= 0.9069) are linear constraints of the same interior-point solve. The platens close in
# steps, each solve started from the last; their pressure is their force over the cell's area.
# K = k E_f is not a measured value for this roving (none could be verified): 50 MPa here.

# +
import json
import os
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from mpi4py import MPI

import textile_fenicsx as tfx
from textile_fenicsx.pipeline.compaction import CompactionTarget, plot_curve
from textile_fenicsx.plot.plotting import yarn_colours

comm = MPI.COMM_WORLD
seed = float(os.environ.get("TEXTILE_FENICSX_SEED", "0.5"))
targets = [float(v) for v in os.environ.get("TEXTILE_FENICSX_TARGETS", "0.45 0.5 0.55").split()]
modulus = float(os.environ.get("TEXTILE_FENICSX_MODULUS", "50"))
voxel = float(os.environ.get("TEXTILE_FENICSX_VOXEL", "0.35"))  # the permeability's voxels in plan [mm]
layers = int(os.environ.get("TEXTILE_FENICSX_LAYERS", "4"))  # and through the thickness
out = Path(os.environ.get("TEXTILE_FENICSX_OUT", "output/compaction_satin"))
model = Path(__file__).resolve().parents[1] / "reference" / "models" / "satin4_fibres.tg3"
tfx.show_progress()
start = time.perf_counter()
satin = tfx.read(model)
# -

# One run per target: each presses the relaxed fabric in steps 0.05 of Vf apart or less (the last
# run's curve holds every step on the way to the highest target, and keeps the corrected model of
# each of its points: `step_models`).

runs = {}
for vf in targets:
    steps = max(2, int(np.ceil((vf - 0.3) / 0.05)))
    target = CompactionTarget(modulus, vf=vf, steps=steps, step_models=vf == targets[-1])
    runs[vf] = tfx.solve(satin, seed=seed, comm=comm, compaction=target)
    verdict = runs[vf].verdict  # collective: every rank measures
    if comm.rank == 0:
        print(f"Vf {vf}: {runs[vf].summary_line()}")
        assert verdict["passed"], verdict["failures"]

# ## The permeability as the fabric is pressed
#
# Each point of the last curve, its corrected model meshed in voxels (`voxel` mm in plan, `layers`
# through the platens' gap: the same grid at every point, stretched to its thickness), and its
# three periodic Stokes-Brinkman cell problems (tfx.permeability): Stokes in the pores, Brinkman in
# the yarns with Gebart's permeability at their fibre fraction, the fibres' radius from the model's
# fibre data (17 um across). Pressing closes the pores between the yarns and packs the fibres in
# them, so K falls as Vf rises. Voxels this coarse resolve the gaps between neighbouring yarns (0.3
# mm here) poorly: the trend is the point, not the values. At 0.35 mm and 4 layers each point is
# 124 000 unknowns, 35-55 s on two cores (5 of the demo's 6 minutes); 0.4 mm and 3 layers took 13-20
# s a point, but Kxx fell 20-fold at the last (the voxels closed the gaps between the yarns), and
# under 3 layers Kzz jumps where the layer count changes.

last = runs[targets[-1]]
radius = satin.yarns[0].fibres.diameter / 2
permeabilities = tfx.permeability_curve(last, fibre_radius=radius, size=voxel, layers=layers, comm=comm)
diagonals = np.array([np.diag(k.K_m2) for k in permeabilities])
if comm.rank == 0:
    print(f"{'Vf':>6} {'voxels':>7} {'porosity':>9} {'Kxx [m^2]':>11} {'Kyy [m^2]':>11} {'Kzz [m^2]':>11} {'s':>5}")
    for vf, k, d in zip(last.compaction.vf, permeabilities, diagonals):
        print(f"{vf:6.3f} {k.vf:7.3f} {k.porosity:9.3f} {d[0]:11.4g} {d[1]:11.4g} {d[2]:11.4g} "
              f"{k.seconds['total']:5.1f}")
    assert np.all(diagonals[-1] < diagonals[0]), diagonals  # pressed, the cell lets less through

# The curve of the highest target (pressure and K against Vf), and the satin cut along its first
# warp's centre: the idealised model and the three pressed ones (z in mm, drawn at the same scale).

lines = None
if comm.rank == 0:
    from textile_fenicsx.pipeline.outputs import cut_lines

    out.mkdir(parents=True, exist_ok=True)
    plot_curve(last.compaction, out / "compaction.png", f"{satin.name}: compaction, K = {modulus:g} MPa")
    (out / "compaction.json").write_text(json.dumps(last.compaction.as_dict(), indent=1))
    lines = cut_lines(satin)[:1]
lines = comm.bcast(lines, root=0)
label, a, b = lines[0]
a, b = np.asarray(a, float), np.asarray(b, float)
t = np.linspace(0, 1, 800)
xy = a + np.outer(t, b - a)
models = [("idealised (TexGen)", satin)] + [
    (f"Vf {vf:g}: {r.compaction.pressure[-1]:.3g} MPa, {r.compaction.thickness[-1]:.3f} mm", r.corrected)
    for vf, r in runs.items()]
envelopes = [m.columns(xy).envelope(len(m.yarns)) for _, m in models]  # collective-free: numpy rays
if comm.rank == 0:
    colours = yarn_colours(len(satin.yarns))
    fig, axes = plt.subplots(len(models), 1, figsize=(10, 1.9 * len(models)), sharex=True, sharey=True,
                             constrained_layout=True)
    s = t * np.linalg.norm(b - a)
    shown = {}
    for ax, (title, textile), (bot, top) in zip(axes, models, envelopes):
        for i in range(len(textile.yarns)):
            if not np.all(np.isnan(bot[:, i])):
                shown[i] = ax.fill_between(s, bot[:, i], top[:, i], where=~np.isnan(bot[:, i]), color=colours[i],
                                           alpha=0.8, linewidth=0)
        ax.set_title(title, fontsize=10)
        ax.set_ylabel("z [mm]")
    axes[-1].set_xlabel(f"distance along the cut ({label}) [mm]")
    fig.legend([shown[i] for i in sorted(shown)], [satin.yarns[i].name for i in sorted(shown)],
               loc="outside lower center", ncol=8, fontsize=8, frameon=False)
    fig.savefig(out / "cross_sections.png", dpi=120)
    plt.close(fig)
    print(f"written to {out}/ in {time.perf_counter() - start:.0f} s")
