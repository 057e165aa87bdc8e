"""A tet mesh's settings and what they fix before any meshing (mesher.py drives it): the options
(TetOptions), the mesh's arrays (TetMesh), the gap the mesh is made for (default_gap), the smallest
element size, the box (box_corners) and the estimate of its tets that refuses a size too fine
(check_size).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from textile_fenicsx.common.errors import TextileError, check_positive
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.box import DEFAULT_SIZE
from textile_fenicsx.volume.tet import solids

# Memory of the mesh process per tet [bytes] and tets per mm^3 of box at size h, x h^3: measured on
# the corrected satin4 at size 0.25 (peak 1.4 GB and 300 756 tets in 127 mm^3: 4.7 kB and 37).
BYTES_PER_TET = 5e3
TETS_PER_VOLUME = 37.0


@dataclass(frozen=True)
class TetOptions:
    """Tet-mesh settings (lengths in mm).

    size: largest element size. gap: the least gap between yarns (and between a yarn and the box's
    top or bottom face, with gap / 2 there) the mesh is made for; default 5 % of the thinnest yarn's
    height. grading: element size per unit of local gap (the sum of the distances to the two
    nearest yarns). curvature: elements per 2 pi of the yarn surfaces' curvature (doubled, up to
    twice, where a yarn's surface mesh encloses more than surface_mesh.SHORT less than its
    surface). spacing: station spacing along the yarns (at least one per master node, and 10
    degrees of the path's turning at most: solids.TURN); points: points per section, spaced evenly
    along its perimeter (the spline through 24 of them undershoots the tips of the 3D weaves'
    thin flat sections: each yarn's solid 0.75 % short, every yarn -0.94..-1.05 % after meshing on
    l2l_w2f3_b3_0011; with 48, -0.35..-0.71 %; docs/tet_mesh.md). z_range:
    the box's (zmin, zmax), default the yarns' extent padded by gap / 2. shrink: allow the last
    resort (sections scaled down to open the gap; the volume lost is reported). max_elements:
    refuse a size estimated to give more tets. threads: gmsh's threads (at most 2 here).
    """

    size: float = DEFAULT_SIZE["tet"]
    gap: float | None = None
    grading: float = 3.0
    curvature: int = 24
    spacing: float = 0.25
    points: int = 48
    z_range: tuple | None = None
    shrink: bool = False
    max_elements: int = 3_000_000
    threads: int = 2
    memory_limit: float | None = None

    def __post_init__(self):
        check_positive("tet size", self.size)
        if self.gap is not None:
            check_positive("tet gap", self.gap)
        check_positive("tet grading", self.grading)
        check_positive("tet spacing", self.spacing)
        if int(self.points) < 8:
            raise TextileError(f"tet points per section must be >= 8, got {self.points!r}")
        if self.z_range is not None and not float(self.z_range[1]) > float(self.z_range[0]):
            raise TextileError(f"tet z_range must be (zmin, zmax) with zmax > zmin, got {self.z_range!r}")


@dataclass
class TetMesh:
    """Linear tets of the cell (on rank 0).

    points (N, 3) [mm]; tets (E, 4) node indices, positive orientation; phase (E,) 0 the matrix,
    1 + i yarn i; fibre (E, 3) unit fibre direction of yarn elements (0 in the matrix); lo, hi the
    box's corners [mm]; names: phase -> name; report: the mesh report (JSON-ready).
    """

    points: np.ndarray
    tets: np.ndarray
    phase: np.ndarray
    fibre: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    names: list
    report: dict = field(default_factory=dict)


def smallest(options: TetOptions, gap: float, height: float) -> float:
    """The smallest element size [mm]: half the gap, else a sixth of the largest size but no more
    than an eighth of the thinnest yarn's height (the curvature of a lens or ellipse tip would ask
    for elements of a hundredth of a mm all along every yarn's edges: 4x the tets on the plain
    weave for 0.3 % of its volume; coarser, the tips' chords lose more than 1 % of it)."""
    return max(gap / 2, min(options.size / 6, height / 8))


def thinnest_height(textile: Textile) -> float:
    """The least section height of any yarn [mm] (up extent of its section polygons)."""
    least = np.inf
    for y in textile.yarns:
        sec = y.section_points(y.stations(textile.resolution.spacing, 1), 32)
        least = min(least, float((sec[..., 1].max(axis=1) - sec[..., 1].min(axis=1)).min()))
    return least


def default_gap(textile: Textile, options: TetOptions) -> float:
    """The gap the mesh is made for [mm]: options.gap, else 5 % of the thinnest yarn's height."""
    return options.gap if options.gap is not None else 0.05 * thinnest_height(textile)


def box_corners(textile: Textile, options: TetOptions, gap: float,
                shrink: float) -> tuple[np.ndarray, np.ndarray]:
    """The box's corners (lo, hi) [mm] at the cell's origin: the cell in x, y; in z, `z_range`, else
    the yarns' own extent (their sections shrunk by `shrink`) padded by gap / 2."""
    c = textile.cell
    if options.z_range is not None:
        z0, z1 = map(float, options.z_range)
    else:
        z0, z1 = np.inf, -np.inf
        for i in range(len(textile.yarns)):  # sampled finer than the splines' points: they overshoot
            sec = solids.yarn_sections(textile, i, options.spacing / 2, 4 * options.points, shrink)
            z0, z1 = min(z0, sec[..., 2].min()), max(z1, sec[..., 2].max())
        z0, z1 = z0 - gap / 2, z1 + gap / 2
    return np.array([c.x0, c.y0, z0]), np.array([c.x0 + c.lx, c.y0 + c.ly, z1])


def check_size(lo: np.ndarray, hi: np.ndarray, options: TetOptions) -> int:
    """Refuse, before meshing, a size estimated to give more than max_elements tets or to need more
    memory than the limit (memory.check; default: what the system has available). Returns the
    estimate."""
    from textile_fenicsx.common import memory

    estimate = int(TETS_PER_VOLUME * float(np.prod(hi - lo)) / options.size**3)
    if estimate > options.max_elements:
        raise TextileError(f"tet size {options.size:g} mm would give about {estimate:.3g} tets, more than the limit "
                           f"of {options.max_elements:.3g}; use a larger size")
    memory.check(estimate * BYTES_PER_TET, what=f"tet size {options.size:g} mm would give about {estimate:.3g} "
                 "tets and", hint="use a larger size", limit_gb=options.memory_limit)
    return estimate
