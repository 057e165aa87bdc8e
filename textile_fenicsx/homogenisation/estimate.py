"""Homogenising a model with the discretisation error of its properties (issue 72): the model meshed
twice or more, each mesh finer by volume.refinement.RATIO, and the engineering constants and
conductivities of the finest with their grid convergence index (volume/refinement.py).

    result = homogenise_model(textile, VolumeOptions("voxel"), "e-glass", "epoxy", accuracy=0.01)
    result.error["quantities"]["Ex"]   # value, error [MPa], relative_error, extrapolated, order
"""

from __future__ import annotations

from dataclasses import replace

from mpi4py import MPI

from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.homogenisation.effective import Homogenised, HomogeniseOptions, homogenise
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.refinement import Level, converge
from textile_fenicsx.volume.stage import VolumeOptions, mesh_cell
from textile_fenicsx.volume.voxel_sizes import SCATTER

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
    """The textile meshed by `volume` and homogenised (homogenise), on that mesh and on one with
    every element size volume.refinement.RATIO times larger, then on finer ones until every
    property's estimated error is within `accuracy` (a fraction) where one is asked. Returns the
    finest mesh's result, its `error` the estimate (Estimate.to_dict), at least voxel_sizes.SCATTER
    of each value. Voxel meshes only (a tet mesh's size does not coarsen it: TextileError).
    Collective."""
    if volume.kind != "voxel":
        raise TextileError("the error estimate needs voxel meshes (--kind voxel): a tet mesh's elements are fitted to "
                           "the gaps between yarns and its curvature, so a mesh of larger size is not a coarser one "
                           "(on the cross-ply, 1.5 x the size gave 0.98 x the tets; with the gaps' grading scaled too, "
                           "1.36 x). Homogenise a tet mesh "
                           "from volume-mesh without an estimate")
    options = options or HomogeniseOptions()

    def solve_at(scale: float) -> Level[Homogenised]:
        cell = mesh_cell(textile, replace(volume, scale=scale), comm)
        f = cell.fields
        result = homogenise(f.mesh, f.phase, f.direction, f.yarn_vf, fibre, matrix, options)
        return Level(result, quantities(result), int(cell.report["elements"]), int(result.dofs["elasticity"]), scale)

    result, estimate = converge(solve_at, accuracy, "homogenising", SCATTER)
    result.error = estimate.to_dict()
    return result
