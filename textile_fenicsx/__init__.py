"""textile_fenicsx: predicts the real geometry of woven textiles by plate energy minimisation.

    import textile_fenicsx as tfx
    run = tfx.solve(tfx.read("satin4.tg3"), seed=0.5)
    run.corrected, run.metrics, run.write("out/")

Data flows one way, and the subpackages are its stages (docs/DESIGN.md section 2):
model -> plate (projected mesh, forms, contact solve) -> correction -> pipeline (compaction, outputs)
-> volume (voxel and tet meshes) -> homogenisation; io reads and writes model files, plot draws,
cli is the command line and common holds what they all share. The one-call functions (api.py)
import the numerical stack only when called. Under mpirun with more than one rank, an uncaught
exception on any rank ends every rank (common/parallel.py).
"""

from textile_fenicsx.common.parallel import install_excepthook as _install_excepthook

_install_excepthook()  # under mpirun with several ranks: an uncaught exception ends every rank


from textile_fenicsx.api import (  # noqa: E402
    build,
    homogenise,
    homogenise_model,
    permeability,
    permeability_curve,
    permeability_model,
    read,
    show_progress,
    solve,
    volume_mesh,
)
from textile_fenicsx.version import __version__  # noqa: E402

__all__ = ["__version__", "build", "homogenise", "homogenise_model", "permeability", "permeability_curve",
           "permeability_model", "read", "show_progress", "solve", "volume_mesh"]
