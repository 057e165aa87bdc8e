# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
# ---

# # From TexGen's idealised satin to the composite's stiffness
#
# TexGen's 4-harness satin (`reference/models/satin4_fibres.tg3`: yarns 2.5 x 0.35 mm, spacing
# 2.8 mm, E-glass rovings of 1200 tex at 2.55 g/cm^3, i.e. an intra-yarn fibre fraction of 0.685),
# in an epoxy matrix. Three cells of the same fabric, meshed and homogenised:
#
# 1. **idealised, voxel**: TexGen's cell as it is. Its yarns interpenetrate; every voxel whose centre
#    lies in two yarns is counted, reported and given to the yarn it lies deepest in.
# 2. **corrected, voxel**: the cell after `solve` (no interpenetration, thicker: 0.70 -> 0.96 mm).
# 3. **corrected, tet**: the same, solved with a minimum gap between yarns (5 % of the thinnest
#    yarn's height, held by the exact contact: no yarn volume is lost) and meshed with conforming
#    tetrahedra.
#
# It shows how to: correct a model (`tfx.solve`), mesh its periodic cell (`tfx.volume_mesh`),
# homogenise it (`tfx.homogenise`: six periodic elastic cell problems and three thermal ones), and
# look at a cell problem's strain energy density.
#
# ## Mathematical formulation
#
# For each unit mean strain E (Voigt order 11 22 33 23 13 12, engineering shears) the periodic
# fluctuation v solves  int eps(w) : C(x) : (E + eps(v)) dx = 0  for every periodic w; the effective
# stiffness is the mean energy  C_ij = 1/|Y| int (E_i + eps(v_i)) : C : (E_j + eps(v_j)) dx. Yarns are
# transversely isotropic about their fibre direction, with Chamis' micromechanics at their fibre
# fraction; the matrix is isotropic.

# +
import json
import os
import time
from pathlib import Path

from mpi4py import MPI

import textile_fenicsx as tfx

comm = MPI.COMM_WORLD
seed = float(os.environ.get("TEXTILE_FENICSX_SEED", "0.5"))
sizes = {"voxel": float(os.environ.get("TEXTILE_FENICSX_VOXEL", "0.1")),
         "tet": float(os.environ.get("TEXTILE_FENICSX_TET", "0.25"))}
kinds = os.environ.get("TEXTILE_FENICSX_KINDS", "voxel tet").split()
degree = int(os.environ.get("TEXTILE_FENICSX_DEGREE", "2"))
out = Path(os.environ.get("TEXTILE_FENICSX_OUT", "output/homogenise_satin"))
model = Path(__file__).resolve().parents[1] / "reference" / "models" / "satin4_fibres.tg3"
tfx.show_progress()
start = time.perf_counter()
# -

# The idealised model, and its corrections (the second one holds the tet mesher's gap):

idealised = tfx.read(model)
corrected = tfx.solve(idealised, seed=seed, comm=comm).corrected
cells = {"idealised, voxel": (idealised, "voxel")}
if "voxel" in kinds:
    cells["corrected, voxel"] = (corrected, "voxel")
if "tet" in kinds:
    from textile_fenicsx.plate.solver import SolverOptions
    from textile_fenicsx.volume.tet.options import TetOptions, default_gap

    gap = default_gap(idealised, TetOptions())
    gapped = tfx.solve(idealised, seed=seed, comm=comm, solver=SolverOptions(min_gap=gap)).corrected
    cells["corrected, tet"] = (gapped, "tet")

# Mesh and homogenise each cell (E-glass in epoxy, the presets; their sources are in
# `textile_fenicsx/homogenisation/materials.py`):

results, meshes = {}, {}
for name, (textile, kind) in cells.items():
    folder = out / name.replace(", ", "_")
    meshes[name] = tfx.volume_mesh(textile, kind=kind, size=sizes[kind], comm=comm)
    meshes[name].write(folder)
    results[name] = tfx.homogenise(meshes[name], fibre="e-glass", matrix="epoxy", comm=comm, degree=degree)
    results[name].write(folder, comm)

# The engineering constants, the fibre volume fraction, and each against the corrected cell's
# first mesh:

# +
keys = ["Ex", "Ey", "Ez", "Gxy", "Gxz", "Gyz", "nuxy", "nuxz", "nuyz"]
reference = results[next(n for n in results if n.startswith("corrected"))] if len(results) > 1 else None
rows = []
for name, r in results.items():
    c = r.constants
    rep = meshes[name].report
    row = {"cell": name, "elements": rep["elements"], "dofs": r.dofs["elasticity"], "Vf": r.fibre_fraction,
           **{k: float(c[k]) for k in keys}}
    if reference is not None:
        row["change_%"] = {k: 100 * (c[k] / reference.constants[k] - 1) for k in keys}
    overlap = rep.get("overlap", {})
    row["overlap_mm3"] = overlap.get("volume", 0.0)
    rows.append(row)
if comm.rank == 0:
    print(f"{'cell':18s} {'elements':>9s} {'Vf':>6s} " + " ".join(f"{k:>7s}" for k in keys))
    for row in rows:
        print(f"{row['cell']:18s} {row['elements']:9d} {row['Vf']:6.3f} "
              + " ".join(f"{row[k]:7.0f}" if not k.startswith("nu") else f"{row[k]:7.3f}" for k in keys))
        if "change_%" in row:
            print(f"{'  vs corrected':18s} {'':9s} {'':6s} " + " ".join(f"{row['change_%'][k]:+6.1f}%" for k in keys))
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.json").write_text(json.dumps(rows, indent=1))
# -

# ## Pictures
#
# A cut through each cell along a warp (x, at the centre of the warp yarn at y = 0, in the plane of
# its path), coloured by phase: the idealised cell's yarns cross each other, the corrected ones lie
# on each other; the voxels' staircase beside the tetrahedra's conforming faces.

# +
from textile_fenicsx.plot.volume_figures import phase_cuts, strain_energy_cut  # noqa: E402

if comm.rank == 0:
    phase_cuts({name: out / name.replace(", ", "_") / "volume.vtu" for name in cells}, 0.0,
               out / "phase_cuts.png")
# -

# The strain energy density of the cell stretched along x (a mean strain of 0.1 % in xx) on the
# last cell: the warps along x carry it, the wefts and the matrix between them little.

last = list(meshes)[-1]
strain_energy_cut(meshes[last].fields, "e-glass", "epoxy", 0, 1e-3, 0.0, out / "strain_energy.png", degree)

if comm.rank == 0:
    print(f"homogenise_satin: {len(cells)} cells in {time.perf_counter() - start:.0f} s; outputs in {out}/")
