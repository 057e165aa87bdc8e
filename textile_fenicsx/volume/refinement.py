"""The discretisation error of a cell's properties, by grid convergence (issue 72).

A property computed on a volume mesh (a modulus, a permeability) differs from its value on an
infinitely fine mesh of the same model: the staircase or facets of the yarns' surfaces and the
finite elements. `converge` meshes the model again with every element size scaled by RATIO, solves
there too, and estimates the error of the finer result by Richardson's extrapolation, reported as
Roache's grid convergence index (GCI: Roache, "Perspective: a method for uniform reporting of grid
refinement studies", J. Fluids Eng. 116, 405-413, 1994; the three-mesh procedure of Celik et al.,
J. Fluids Eng. 130, 078001, 2008):

    e = (f1 - f2) / (r^p - 1),   f_extrapolated = f1 + e,   GCI = Fs |e|

with f1 on the finer mesh, f2 on the coarser, r = (n1 / n2)^(1/3) their ratio of element size (from
the element counts n), and p the order of convergence. With two meshes p is assumed (ORDER: 1, the
order measured on voxels, docs/volume.md "Voxel sizes"; tets converge faster, so the estimate is
then pessimistic) and Fs = 3; with three meshes whose differences keep their sign, p is observed
(bounded to ORDER_BOUNDS) and Fs = 1.25. The converged value is expected within f1 +- GCI.

Richardson's extrapolation needs the values to move smoothly with the element size. A voxel mesh's
do not quite: the grid samples the yarns' surfaces at its centres, and grids a few percent apart
scatter about their trend (docs/volume.md, "Voxel sizes"). Two such grids can agree by chance while
both are off, so a caller may give a floor: the error reported is then at least that fraction of the
value (voxel_sizes.SCATTER for voxels; none for conforming tets).

With an accuracy asked (a fraction of each value), the meshes are refined by RATIO until every
quantity's GCI is within it, or until MAX_MESHES or a mesh that cannot be made or solved (the memory
guard): the finest result is then returned with the estimate reached and why it stopped.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Generic, TypeVar

import numpy as np
from mpi4py import MPI

from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.stage import CellMesh, VolumeOptions, mesh_cell
from textile_fenicsx.volume.voxel_sizes import SCATTER

log = logging.getLogger(__name__)

RATIO = 1.5  # each coarser mesh's element sizes over the next finer one's [-]
ORDER = 1.0  # the order assumed with two meshes [-]
ORDER_BOUNDS = (0.5, 2.0)  # an observed order is held within these [-]
SAFETY = {2: 3.0, 3: 1.25}  # Roache's safety factor Fs with two meshes, and three with an observed order
MAX_MESHES = 5  # the most meshes one accuracy asked may take

R = TypeVar("R")


@dataclass
class Estimate:
    """Each quantity's value on the finest mesh, its estimated error (GCI, same units), its
    extrapolated value and the order used; the meshes, coarse to fine (elements, unknowns, scale)."""

    values: dict[str, float]
    errors: dict[str, float]
    extrapolated: dict[str, float]
    orders: dict[str, float]
    observed: dict[str, bool]
    meshes: list[dict[str, Any]] = field(default_factory=list)
    accuracy: float | None = None
    stopped: str | None = None  # why the refinement stopped short of the accuracy, where it did
    floor: float = 0.0  # the least relative error reported (module docstring)

    def relative(self) -> dict[str, float]:
        """Each error over its value's magnitude (inf where the value is 0 and the error is not)."""
        return {k: (e / abs(self.values[k]) if self.values[k] else (0.0 if e == 0 else float("inf")))
                for k, e in self.errors.items()}

    def worst(self) -> tuple[str, float]:
        """The quantity with the largest relative error, and that error."""
        rel = self.relative()
        name = max(rel, key=lambda k: rel[k])
        return name, rel[name]

    def met(self) -> bool:
        """Whether every relative error is within the accuracy asked (True where none was)."""
        return self.accuracy is None or self.worst()[1] <= self.accuracy

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the method, the meshes and each quantity's estimate."""
        rel = self.relative()
        return {"method": "grid convergence: Richardson's extrapolation from the two finest meshes, reported as "
                          "Roache's GCI = Fs |f1 - f2| / (r^p - 1) (Fs 3 with the order p assumed 1, 1.25 with p "
                          "observed on three meshes); the converged value is expected within value +- error",
                "meshes": self.meshes, "accuracy_asked": self.accuracy, "accuracy_met": self.met(),
                "stopped": self.stopped, "floor": self.floor,
                "quantities": {k: {"value": self.values[k], "error": self.errors[k], "relative_error": rel[k],
                                   "extrapolated": self.extrapolated[k], "order": self.orders[k],
                                   "order_observed": self.observed[k]} for k in self.values}}


def error_summary(error: dict[str, Any] | None) -> str:
    """'; estimated error at most P % (Q)' for an estimate's to_dict, its largest relative error; ''
    for none (a summary line's end)."""
    if error is None:
        return ""
    rel = {k: q["relative_error"] for k, q in error["quantities"].items()}
    worst = max(rel, key=lambda k: rel[k])
    return f"; estimated error at most {100 * rel[worst]:.2g} % ({worst})"


def mesh_ratio(finer: float, coarser: float) -> float:
    """The ratio of element sizes of two 3D meshes from their element counts [-]."""
    return float((finer / coarser) ** (1 / 3))


def _observed_order(f: Sequence[float], r21: float, r32: float) -> float | None:
    """The order observed on three meshes (f coarse to fine), by Celik et al.'s fixed point; None
    where the differences change sign (oscillation) or vanish."""
    e32, e21 = f[1] - f[0], f[2] - f[1]
    if e32 == 0 or e21 == 0 or np.sign(e32) != np.sign(e21):
        return None
    p = ORDER
    for _ in range(50):
        q = np.log((r21**p - 1) / (r32**p - 1))
        p_new = abs(np.log(abs(e32 / e21)) + q) / np.log(r21)
        if abs(p_new - p) < 1e-10:
            break
        p = p_new
    return float(np.clip(p, *ORDER_BOUNDS))


def grid_convergence(values: Sequence[dict[str, float]], elements: Sequence[float], floor: float = 0.0) -> Estimate:
    """The estimate of each quantity of the finest mesh from its values on two or more meshes
    (`values` and `elements`, the meshes' element counts, coarse to fine), each error at least
    `floor` times its value's magnitude: module docstring."""
    if len(values) < 2 or len(values) != len(elements):
        raise ValueError("grid convergence needs the values on two meshes or more, one per element count")
    r = [mesh_ratio(elements[i + 1], elements[i]) for i in range(len(elements) - 1)]
    if min(r) <= 1:
        raise ValueError(f"the meshes must be finer one after the other, got element counts {list(elements)}")
    est = Estimate({}, {}, {}, {}, {}, floor=floor)
    for k in values[-1]:
        f = [float(v[k]) for v in values]
        p = _observed_order(f[-3:], r[-1], r[-2]) if len(f) >= 3 else None
        e = (f[-1] - f[-2]) / (r[-1] ** (p or ORDER) - 1)
        est.values[k], est.extrapolated[k] = f[-1], f[-1] + e
        est.errors[k] = max(SAFETY[3 if p is not None else 2] * abs(e), floor * abs(f[-1]))
        est.orders[k], est.observed[k] = p or ORDER, p is not None
    return est


@dataclass(frozen=True)
class Level(Generic[R]):
    """One mesh's result: what `solve` returned, its quantities, elements and unknowns."""

    result: R
    quantities: dict[str, float]
    elements: int
    unknowns: int
    scale: float


def converge(solve_at: Callable[[float], Level[R]], accuracy: float | None = None,
             what: str = "the cell's properties", floor: float = 0.0) -> tuple[R, Estimate]:
    """The finest result and its estimate: `solve_at(scale)` meshes the model with every element
    size times `scale` and solves on it. Meshes at RATIO and 1, then, where an `accuracy` (a
    fraction) is asked and not met, at 1 / RATIO, 1 / RATIO^2 ... up to MAX_MESHES. A finer mesh
    that fails with a TextileError (the memory guard) ends the refinement: the estimate says why
    (`stopped`) and is not met. A failure on the first two meshes is raised. floor: the least
    relative error reported (grid_convergence)."""
    if accuracy is not None and not 0 < accuracy < 1:
        raise TextileError(f"the accuracy asked must be a fraction between 0 and 1 (e.g. 0.01 for 1 %), got {accuracy}")
    if accuracy is not None and accuracy < floor:
        raise TextileError(f"the accuracy asked, {100 * accuracy:.3g} %, is finer than these meshes can show: their "
                           f"values scatter by {100 * floor:.3g} % about their trend (docs/volume.md); ask at least "
                           "that")
    levels: list[Level[R]] = []
    scale = RATIO
    while True:
        log.info("%s on a mesh of element sizes x %.3g (%d of at most %d meshes)", what, scale, len(levels) + 1,
                 MAX_MESHES if accuracy is not None else 2)
        try:
            levels.append(solve_at(scale))
        except TextileError as e:
            if len(levels) < 2:
                raise
            est = _estimate(levels, accuracy, floor)
            est.stopped = f"the mesh of element sizes x {scale:.3g} failed: {e}"
            log.warning("%s: the refinement stopped at an estimated error of %.2g %% (%s): %s", what,
                        100 * est.worst()[1], est.worst()[0], est.stopped)
            return levels[-1].result, est
        if len(levels) >= 2:
            est = _estimate(levels, accuracy, floor)
            name, rel = est.worst()
            log.info("%s: largest estimated error %.2g %% (%s) on %d unknowns", what, 100 * rel, name,
                     levels[-1].unknowns)
            if est.met():
                return levels[-1].result, est
            if len(levels) >= MAX_MESHES:
                est.stopped = f"{MAX_MESHES} meshes, the most one accuracy may take"
                return levels[-1].result, est
        scale /= RATIO


def _estimate(levels: Sequence[Level[Any]], accuracy: float | None, floor: float) -> Estimate:
    est = grid_convergence([lv.quantities for lv in levels], [lv.elements for lv in levels], floor)
    est.meshes = [{"scale": lv.scale, "elements": lv.elements, "unknowns": lv.unknowns} for lv in levels]
    est.accuracy = accuracy
    return est


def converge_model(textile: Textile, volume: VolumeOptions,
                   compute: Callable[[CellMesh], tuple[R, dict[str, float], int]], accuracy: float | None = None,
                   what: str = "the cell's properties", comm: MPI.Comm = MPI.COMM_WORLD) -> tuple[R, Estimate]:
    """`converge` over voxel meshes of the textile: `volume` scaled (VolumeOptions.scale), each mesh
    given to `compute`, which returns (its result, the quantities to estimate, its unknowns); the
    floor is the voxels' SCATTER. A tet mesh is refused: its elements are fitted to the gaps between
    yarns and to their curvature, so a larger size does not coarsen it (on the cross-ply, 1.5 x the
    size gave 0.98 x the tets; with the gaps' grading scaled too, 1.36 x). Collective."""
    if volume.kind != "voxel":
        raise TextileError("the error estimate needs voxel meshes (--kind voxel): a tet mesh's elements are fitted to "
                           "the gaps between yarns and its curvature, so a mesh of larger size is not a coarser one "
                           "(on the cross-ply, 1.5 x the size gave 0.98 x the tets; with the gaps' grading scaled too, "
                           "1.36 x); a tet mesh from volume-mesh is solved without an estimate")

    def solve_at(scale: float) -> Level[R]:
        cell = mesh_cell(textile, replace(volume, scale=scale), comm)
        result, quantities, unknowns = compute(cell)
        return Level(result, quantities, int(cell.report["elements"]), unknowns, scale)

    return converge(solve_at, accuracy, what, SCATTER)
