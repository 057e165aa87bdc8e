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

import textile_fenicsx as tfx

comm = MPI.COMM_WORLD
seed = float(os.environ.get("TEXTILE_FENICSX_SEED", "0.5"))
out = Path(os.environ.get("TEXTILE_FENICSX_OUT", "output/orthogonal_3d"))
tfx.show_progress()
# -

textile = tfx.build("orthogonal")
textile.name = "orthogonal_3d"
run = tfx.solve(textile, seed=seed, comm=comm)
run.write(out)
if comm.rank == 0:
    print(f"orthogonal_3d: check {'passed' if run.verdict['passed'] else 'FAILED'}; outputs in {out}/")
