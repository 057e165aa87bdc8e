"""Periodic volume meshes of a unit cell: the type both meshers return, and what they share.

A `VolumeMesh` holds first-order elements (hexahedra of the voxel mesher, tetrahedra of the tet
mesher) in VTK/gmsh node order, with one phase per element (0 matrix, 1 + i yarn i) and, per element,
the fibre direction (the unit tangent of the yarn's centreline nearest to the element's centre) and
the yarn's fibre volume fraction. Its box is the periodic cell: the model's cell in plan and, through
the thickness, the yarns' own extent or a mould's (`cell_box`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.model.textile import Textile

log = logging.getLogger(__name__)

KINDS = ("voxel", "tet")
# The tet mesh's element size [mm] where none is given: 0.35, the volume sweep's size
# (docs/sweep.md); on the corrected satin every engineering constant moves by at most 0.07 % from
# 0.35 to 0.25 mm, while 0.25 and 0.2 mm take 1.3 and 1.7 x the unknowns (docs/volume.md,
# "Refinement, and voxel against tet"). A voxel mesh's default sizes are per axis, from the
# yarns (voxel_sizes.py, voxel.default_grid).
DEFAULT_SIZE = {"tet": 0.35}


@dataclass(frozen=True)
class Box:
    """The periodic cell of a volume mesh: lo = (x0, y0, z0), hi = (x1, y1, z1) [mm]; tol: the
    distance [mm] under which points coincide or lie on a face (0: exact)."""

    lo: tuple[float, ...]
    hi: tuple[float, ...]
    tol: float = 0.0

    @property
    def size(self) -> np.ndarray:
        """Side lengths (lx, ly, lz) [mm]."""
        return np.subtract(self.hi, self.lo)

    @property
    def volume(self) -> float:
        """[mm^3]"""
        return float(np.prod(self.size))


@dataclass(eq=False)
class VolumeMesh:
    """A periodic volume mesh of a unit cell (mm).

    kind: "voxel" or "tet". points (N, 3). cells (E, 8) hexahedra or (E, 4) tetrahedra, VTK/gmsh node
    order. phase (E,): 0 matrix, 1 + i yarn i. direction (E, 3): unit fibre direction (0 in matrix).
    yarn_vf (E,): the yarn's intra-yarn fibre volume fraction (0 in matrix). yarn_names: the yarns'
    names, by index. report: what the mesher measured (mesh_report.json).
    """

    kind: str
    box: Box
    points: np.ndarray
    cells: np.ndarray
    phase: np.ndarray
    direction: np.ndarray
    yarn_vf: np.ndarray
    yarn_names: list[str]
    report: dict[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:
        lx, ly, lz = self.box.size
        return (f"VolumeMesh({self.kind}, {len(self.cells)} elements, {len(self.points)} nodes, "
                f"box {lx:g} x {ly:g} x {lz:g} mm, {len(self.yarn_names)} yarns)")

    def element_volumes(self) -> np.ndarray:
        """Each element's volume [mm^3] (signed for tetrahedra: positive when oriented)."""
        p = self.points[self.cells]
        if self.cells.shape[1] == 4:
            return np.einsum("ij,ij->i", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0])) / 6
        return np.prod(p[:, 6] - p[:, 0], axis=1)  # axis-aligned voxels

    def phase_volumes(self) -> np.ndarray:
        """Meshed volume of the matrix and of each yarn, (1 + n_yarns,) [mm^3]."""
        return np.bincount(self.phase, weights=np.abs(self.element_volumes()), minlength=1 + len(self.yarn_names))


def yarn_extent(textile: Textile, n: int = 200) -> tuple[float, float]:
    """The lowest bottom and highest top of the yarns over the cell [mm] (vertical rays on an n x n grid)."""
    xy, _ = textile.cell.grid(n)
    col = textile.columns(xy)
    if len(col.bottom) == 0:
        raise TextileError(f"{textile.name}: no yarn lies over its cell")
    return float(col.bottom.min()), float(col.top.max())


def cell_box(textile: Textile, z_range: tuple[float, float] | None = None) -> Box:
    """The volume mesh's periodic cell: the model's cell in plan; through the thickness z_range (a
    mould's cavity) if given, else the yarns' own extent (the fabric's thickness)."""
    if not textile.cell.periodic:
        raise TextileError(f"{textile.name}: a volume mesh needs a periodic cell; this model is a coupon with free "
                           "edges")
    x0, x1, y0, y1 = textile.cell.bounds
    z0, z1 = yarn_extent(textile) if z_range is None else (float(z_range[0]), float(z_range[1]))
    if not z1 > z0:
        raise TextileError(f"the cell's z range must have zmax > zmin, got ({z0:g}, {z1:g}) mm")
    return Box((x0, y0, z0), (x1, y1, z1))


def model_yarn_volumes(textile: Textile, box: Box, n: int = 400) -> np.ndarray:
    """Each yarn's volume inside the box, measured on the model (vertical rays on an n x n grid) [mm^3]."""
    xy, area = textile.cell.grid(n)
    col = textile.columns(xy)
    length = np.clip(col.top, box.lo[2], box.hi[2]) - np.clip(col.bottom, box.lo[2], box.hi[2])
    return np.bincount(col.yarn, weights=length, minlength=len(textile.yarns)) * area


def element_fields(textile: Textile, centres: np.ndarray, phase: np.ndarray,
                   yarn_vf: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Per element: the unit fibre direction (the tangent of its yarn's centreline nearest to its
    centre, periodic copies included) and its yarn's fibre volume fraction; zero in the matrix."""
    direction = np.zeros((len(phase), 3))
    vf = np.zeros(len(phase))
    for i in range(len(textile.yarns)):
        mine = np.flatnonzero(phase == i + 1)
        if len(mine):
            direction[mine] = textile.fibre_direction(i, centres[mine])
            vf[mine] = yarn_vf[i]
    return direction, vf


def periodic_mismatch(points: np.ndarray, box: Box, tol: float = 1e-10) -> dict[str, Any]:
    """How far the nodes are from periodic (pure numpy and a k-d tree): for each axis, the nodes on
    the + and - faces, how many + face nodes have no image on the - face within tol x the largest
    side (`missing`, `example`: the first of them), the largest distance to an image (`worst`);
    "periodic": no image missing on any axis and as many nodes on both faces of each."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, float).reshape(-1, 3)
    scale = float(np.max(box.size))
    eps = tol * scale
    out: dict[str, Any] = {}
    periodic = True
    for axis, name in enumerate("xyz"):
        lo, hi = box.lo[axis], box.hi[axis]
        plus = points[np.abs(points[:, axis] - hi) <= eps]
        minus = points[np.abs(points[:, axis] - lo) <= eps]
        shift = np.zeros(3)
        shift[axis] = hi - lo
        d = cKDTree(minus).query(plus - shift)[0] if len(plus) and len(minus) else np.full(len(plus), np.inf)
        far = np.flatnonzero(d > eps)
        out[name] = {"plus": len(plus), "minus": len(minus), "missing": len(far),
                     "worst": float(d.max()) if len(d) else 0.0,
                     "example": plus[far[0]].tolist() if len(far) else None}
        periodic &= len(far) == 0 and len(plus) == len(minus)
    out["periodic"] = bool(periodic)
    out["tolerance_mm"] = eps
    return out
