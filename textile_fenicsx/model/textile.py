"""The textile model: a periodic unit cell and its yarns (units: mm; DESIGN.md section 3).

`Cell` is the box, `Resolution` how finely yarn surfaces are discretised, `Textile` the cell with
its yarns (yarn.py) and what its maker states (the thickness it is woven to, how a coupon was
tiled). The geometric queries the pipeline asks of a textile are methods that call queries.py:
- `columns(xy)`: vertical rays through in-plane points; for each point every yarn interval over it
  (bottom and top z), periodic images included;
- `inside(points)`: which yarns contain 3D points; `fibre_direction(i, points)`: local fibre tangent;
- `tubes(i)`: closed tubes of yarn i covering the cell (surfaces.py clips them).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from textile_fenicsx.common import limits
from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.model import queries
from textile_fenicsx.model.cell import Cell, Resolution
from textile_fenicsx.model.queries import RAY_NUDGE, Columns
from textile_fenicsx.model.yarn import Yarn

__all__ = ["RAY_NUDGE", "Cell", "Columns", "Resolution", "Textile", "Tiling"]


@dataclass(eq=False)
class Textile:
    """A unit cell with its yarns (mm, z through the thickness). tiling: for a coupon made by
    `coupon.tile`, how (the unit cell, the repeats, each yarn's source), so that its mesh can be
    the unit cell's repeated; None otherwise. thickness: the thickness the fabric is woven to [mm],
    where its maker states one (a 3D weave's: TexGen's FabricThickness, our orthogonal builder's),
    the default mould of the solve (pipeline.Settings.mould); None otherwise. plies: how many plies
    it stacks (plies.stack, TexGen's CTextileLayered: its yarns come ply by ply), 1 otherwise;
    ply_sizes: the yarns of each ply, where they differ (None, which equal sizes become: as many in
    each; `yarns_per_ply` gives them either way)."""

    cell: Cell
    yarns: list = field(default_factory=list)
    name: str = "textile"
    resolution: Resolution = field(default_factory=Resolution)
    tiling: Tiling | None = None
    thickness: float | None = None
    plies: int = 1
    ply_sizes: tuple[int, ...] | None = None

    def __post_init__(self):
        if not self.yarns:
            raise TextileError(f"textile {self.name!r} has no yarns")
        if not isinstance(self.plies, (int, np.integer)) or self.plies < 1:
            raise TextileError(f"textile {self.name!r}: plies must be a whole number >= 1, got {self.plies!r}")
        sizes = self.yarns_per_ply()
        if len(sizes) != self.plies or min(sizes) < 1 or sum(sizes) != len(self.yarns):
            raise TextileError(f"textile {self.name!r}: {self.plies} plies of {list(sizes)} yarns do not hold its "
                               f"{len(self.yarns)} yarns")
        if len(set(sizes)) == 1:  # as many yarns in each ply: as plies.stack makes them
            self.ply_sizes = None
        if self.thickness is not None:
            limits.check_length(f"textile {self.name!r}: thickness", self.thickness)
        limits.check_many(f"textile {self.name!r}: yarns", len(self.yarns), limits.MAX_YARNS)
        for i, y in enumerate(self.yarns):
            if not isinstance(y, Yarn):
                raise TextileError(f"textile {self.name!r}: yarn {i} is not a Yarn")
            if not y.name:
                y.name = f"yarn {i}"
            if y.periodic and self.cell.periodic:
                self._check_closes(y)
        self._triangles = {}

    def yarns_per_ply(self) -> tuple[int, ...]:
        """How many yarns each ply has, ply by ply (the yarns come ply by ply)."""
        return tuple(self.ply_sizes) if self.ply_sizes else (len(self.yarns) // self.plies,) * self.plies

    def check_size(self) -> None:
        """Refuse a model read from a file or asked for on the command line whose master nodes or
        yarn surfaces are beyond the bounds (limits.py), before any surface is built: the nodes
        per yarn and in all, and the surface points (stations at least every resolution spacing
        along each yarn and 4 per segment, section_points each). Models the pipeline makes (a
        coupon, a corrected model) are not checked: their size follows from checked inputs."""
        for y in self.yarns:
            limits.check_many(f"{y.name}: master nodes", len(y.nodes), limits.MAX_NODES_PER_YARN)
        limits.check_many(f"textile {self.name!r}: master nodes of all yarns", sum(len(y.nodes) for y in self.yarns),
                          limits.MAX_NODES)
        r = self.resolution
        if not isinstance(r, Resolution):
            raise TextileError(f"textile {self.name!r}: resolution must be a Resolution, got {type(r).__name__}")
        stations = sum(float(np.sum(np.maximum(np.ceil(np.linalg.norm(np.diff(y.nodes, axis=0), axis=1) / r.spacing),
                                               4))) for y in self.yarns)
        points = stations * r.section_points
        if points > limits.MAX_SURFACE_POINTS:
            raise TextileError(f"textile {self.name!r}: its yarn surfaces would have about {points:.3g} points "
                               f"(stations every {r.spacing:g} mm along {len(self.yarns)} yarns, {r.section_points} "
                               f"points per section), more than the limit of {limits.MAX_SURFACE_POINTS:.3g}; use a "
                               "larger resolution spacing or fewer section_points")

    def _check_closes(self, yarn: Yarn) -> None:
        """A periodic yarn must come back onto itself after whole cells: its last master node is
        its first moved by a a1 + b a2 (the cell's lattice: (lx, 0) and (shift, ly)) with whole a, b
        (else the pattern is not periodic)."""
        p, c = yarn.period, self.cell
        with np.errstate(over="ignore", invalid="ignore"):
            a, b = c.lattice_coordinates(p[:2])[0]
        tol = 1e-6
        if not (np.isfinite(a) and np.isfinite(b)) or abs(a - round(a)) > tol or abs(b - round(b)) > tol \
                or abs(p[2]) > tol * max(c.lx, c.ly) or (round(a), round(b)) == (0, 0):
            raise TextileError(f"{yarn.name}: not periodic over the cell: its last master node is its first "
                               f"moved by ({p[0]:g}, {p[1]:g}, {p[2]:g}) mm, which is not a whole number of "
                               f"cells ({c.lx:g} x {c.ly:g} mm, no rise); close the path or mark the yarn "
                               "non-periodic")

    def __repr__(self) -> str:
        """One line: name, cell, yarns, master nodes, kinds of section (as DOLFINx and pyvista objects)."""
        kinds = sorted({type(x).__name__ for y in self.yarns for x in y.section.sections()})
        extra = "" if self.cell.periodic else ", free edges"
        if self.cell.shift:
            extra += f", sheared {self.cell.shear_angle:.4g} degrees"
        if self.tiling is not None:
            extra += f", a {self.tiling.nx} x {self.tiling.ny} coupon of {self.tiling.unit.name!r}"
        return (f"<Textile {self.name!r}: cell {self.cell.lx:g} x {self.cell.ly:g} mm{extra}, {len(self.yarns)} yarns "
                f"({sum(len(y.nodes) for y in self.yarns)} master nodes), sections {', '.join(kinds)}>")

    # --- geometric queries (queries.py) ----------------------------------------------------------
    def triangles(self, i: int, region: tuple | None = None) -> np.ndarray:
        """Triangles (T, 3, 3) of yarn i's surface, periodic copies included, that vertical rays
        through `region` (x0, x1, y0, y1; default the cell) can hit (cached; queries.yarn_triangles)."""
        return queries.yarn_triangles(self, i, region, self._triangles)

    def forget_surfaces(self) -> None:
        """Drop the cached yarn triangles (large on coupons) once the queries are done."""
        self._triangles = {}

    def __getstate__(self) -> dict:
        """Pickled without the cached triangles (tens of MB; rebuilt on the first query)."""
        return {**self.__dict__, "_triangles": {}}

    def columns(self, xy, yarns=None) -> Columns:
        """Vertical-ray intervals of every yarn (or those listed) over in-plane points xy (N, 2)."""
        return queries.columns(self, xy, yarns)

    def inside(self, points) -> np.ndarray:
        """(N, n_yarns) booleans: is 3D point k inside yarn i."""
        return queries.inside(self, points)

    def nearest_centreline(self, i: int, points) -> tuple[np.ndarray, np.ndarray]:
        """Positions and unit tangents (N, 3) of yarn i's centreline (periodic copies included) at
        the samples nearest to `points`: (N, 2) in-plane (nearest in plan) or (N, 3) positions."""
        return queries.nearest_centreline(self, i, points)

    def fibre_direction(self, i: int, points) -> np.ndarray:
        """Unit fibre tangents (N, 3) of yarn i at the centreline points nearest to `points`
        ((N, 2) in-plane or (N, 3) positions)."""
        return self.nearest_centreline(i, points)[1]

    def tubes(self, i: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """Closed tubes (points, outward triangles) of yarn i that together cover the cell
        (queries.tubes; surfaces.YarnSurfaces clips them to the cell)."""
        return queries.tubes(self, i)


@dataclass(frozen=True)
class Tiling:
    """How a coupon was made (coupon.tile): the unit cell `unit` repeated nx x ny times; source[i]
    is the unit cell yarn that the coupon's yarn i continues."""

    unit: Textile
    nx: int
    ny: int
    source: tuple
