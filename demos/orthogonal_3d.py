# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
# ---

# # A 3D orthogonal weave with binders (the paper's Fig. 14)
#
# Two warp layers between three weft layers, held by binders that pass over the top wefts and under
# the bottom ones. The binders' through-thickness legs are the steepest parts the projected-plate
# method has to take (slope up to about 9 here; the mesh refuses steeper ones). TexGen's solver never
# converges on this weave: its contact states oscillate.

# +
import os
from pathlib import Path

from mpi4py import MPI

from textile_fenicsx.correct import corrected_textile
from textile_fenicsx.meshes.projected import MeshOptions
from textile_fenicsx.outputs import write_run
from textile_fenicsx.pipeline import run
from textile_fenicsx.solver import PlateParameters, SolverOptions
from textile_fenicsx.weaves import build

comm = MPI.COMM_WORLD
seed = float(os.environ.get("TEXTILE_FENICSX_SEED", "0.5"))
out = Path(os.environ.get("TEXTILE_FENICSX_OUT", "output/orthogonal_3d"))
say = print if comm.rank == 0 else (lambda *_: None)
# -

textile = build("orthogonal")
textile.name = "orthogonal_3d"
params, options, mesh = PlateParameters(), SolverOptions(method="augmented"), MeshOptions(seed)
result = run(textile, mesh, params, options, comm, log=say)
corrected = corrected_textile(textile, result.solution.w, spacing=min(seed / 2, 0.25), n_points=64)
write_run(result, corrected, out, params, options, mesh, log=say)
say(f"orthogonal_3d: outputs in {out}/")
