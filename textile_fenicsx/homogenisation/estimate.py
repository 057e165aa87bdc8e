"""Homogenising a model with the discretisation error of its properties (issue 72): the model meshed
in voxels twice or more, each mesh finer by volume.refinement.RATIO, and the engineering constants
and conductivities of the finest with their grid convergence index (volume/refinement.py).

    result = homogenise_model(textile, VolumeOptions("voxel"), "e-glass", "epoxy", accuracy=0.03)
    result.error["quantities"]["Ex"]   # value, error [MPa], relative_error, extrapolated, order
"""

from __future__ import annotations

from mpi4py import MPI

from textile_fenicsx.homogenisation.effective import Homogenised, HomogeniseOptions, homogenise
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.refinement import converge_model
from textile_fenicsx.volume.stage import CellMesh, VolumeOptions

__all__ = ["homogenise_model", "quantities"]


def quantities(result: Homogenised) -> dict[str, float]:
    """The properties whose error is estimated: the nine engineering constants [MPa, -] and the
    principal conductivities kx, ky, kz [W/(m K)] where computed."""
    q = {k: float(v) for k, v in result.constants.items()}
    if result.K is not None:
        q.update({f"k{a}": float(result.K[i, i]) for i, a in enumerate("xyz")})
    return q


def homogenise_model(textile: Textile, volume: VolumeOptions, fibre, matrix,
                     options: HomogeniseOptions | None = None, accuracy: float | None = None,
                     comm: MPI.Comm = MPI.COMM_WORLD) -> Homogenised:
    """The textile meshed in voxels by `volume` and homogenised (homogenise), on that mesh and on one
    with every size volume.refinement.RATIO times larger, then on finer ones until every
    property's estimated error is within `accuracy` (a fraction) where one is asked. Returns the
    finest mesh's result, its `error` the estimate (Estimate.to_dict). Collective."""
    options = options or HomogeniseOptions()

    def compute(cell: CellMesh) -> tuple[Homogenised, dict[str, float], int]:
        f = cell.fields
        result = homogenise(f.mesh, f.phase, f.direction, f.yarn_vf, fibre, matrix, options)
        return result, quantities(result), int(result.dofs["elasticity"])

    result, estimate = converge_model(textile, volume, compute, accuracy, "homogenising", comm)
    result.error = estimate.to_dict()
    return result
