"""The permeability of a model with its discretisation error (issue 72): the model meshed in voxels
twice or more, each mesh finer by volume.refinement.RATIO, and the diagonal of K on the finest with
its grid convergence index (volume/refinement.py).

    k = permeability_model(textile, VolumeOptions("voxel"), PermeabilityOptions(fibre_radius=0.0035))
    k.error["quantities"]["Kxx"]   # value, error [mm^2], relative_error, extrapolated, order
"""

from __future__ import annotations

from mpi4py import MPI

from textile_fenicsx.flow.effective import Permeability, PermeabilityOptions, permeability
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.refinement import converge_model
from textile_fenicsx.volume.stage import CellMesh, VolumeOptions

__all__ = ["permeability_model"]


def permeability_model(textile: Textile, volume: VolumeOptions, options: PermeabilityOptions | None = None,
                       accuracy: float | None = None, comm: MPI.Comm = MPI.COMM_WORLD) -> Permeability:
    """The textile meshed in voxels by `volume` and its permeability computed (permeability), on
    that mesh and on one with every size volume.refinement.RATIO times larger, then on finer ones
    until Kxx, Kyy and Kzz [mm^2] are within `accuracy` (a fraction) where one is asked. Returns
    the finest mesh's result, its `error` the estimate (Estimate.to_dict). Collective."""
    options = options or PermeabilityOptions()

    def compute(cell: CellMesh) -> tuple[Permeability, dict[str, float], int]:
        result = permeability(cell.fields, options)
        diagonal = {f"K{a}{a}": float(result.K[i, i]) for i, a in enumerate("xyz")}
        return result, diagonal, result.dofs

    result, estimate = converge_model(textile, volume, compute, accuracy, "the permeability", comm)
    result.error = estimate.to_dict()
    return result
