"""textile_fenicsx: predicts the real geometry of woven textiles by plate energy minimisation.

    import textile_fenicsx as tfx
    run = tfx.solve(tfx.read("satin4.tg3"), seed=0.5)
    run.corrected, run.metrics, run.write("out/")

Data flows one way (docs/DESIGN.md section 2):
textile model -> projected mesh (`textile_fenicsx.meshes`) -> UFL forms (`textile_fenicsx.forms`)
-> solve (`textile_fenicsx.solver`) -> corrected textile (`correct`, checked by `verify`) -> exports.
The one-call functions (api.py) import the numerical stack only when called. Under mpirun with
more than one rank, an uncaught exception on any rank ends every rank (parallel.py).
"""

from pathlib import Path as _Path

__version__ = "0.1.0"


def _mount_source_subpackages() -> None:
    """Make `forms/` and `meshes/` import as `textile_fenicsx.forms` and `textile_fenicsx.meshes`.

    An install maps those top-level folders inside the package (pyproject.toml, package-dir).
    In a source checkout they sit beside it; adding the checkout to this package's search path
    gives the same import names without installing.
    """
    here = _Path(__file__).resolve().parent
    top = here.parent
    if not (here / "forms").is_dir() and (top / "forms" / "__init__.py").is_file():
        __path__.append(str(top))  # noqa: F821 (the package's own __path__)


_mount_source_subpackages()


from textile_fenicsx.parallel import install_excepthook as _install_excepthook  # noqa: E402

_install_excepthook()  # under mpirun with several ranks: an uncaught exception ends every rank


from textile_fenicsx.api import build, homogenise, read, show_progress, solve, volume_mesh  # noqa: E402

__all__ = ["__version__", "build", "homogenise", "read", "show_progress", "solve", "volume_mesh"]
