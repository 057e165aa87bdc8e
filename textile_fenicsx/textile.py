"""The textile: a periodic unit cell and its yarns, with vectorised geometric queries.

Every yarn surface is a tube of section polygons at stations along its centreline (spacing and
points per section from `Resolution`), repeated by the yarn's repeat vectors. Queries:
- `columns(xy)`: vertical rays through in-plane points; for each point every yarn interval over it
  (bottom and top z), periodic images included;
- `inside(points)`: which yarns contain 3D points; `fibre_direction(i, points)`: local fibre tangent;
- `surface(i)`: a closed triangulated surface of yarn i clipped to the cell (pyvista PolyData).
"""

from dataclasses import dataclass, field
from itertools import product

import numpy as np
from scipy.spatial import cKDTree

from textile_fenicsx import limits
from textile_fenicsx.errors import TextileError
from textile_fenicsx.yarn import Yarn

# Vertical rays are nudged off the query points by this much [mm] (a fixed irrational direction), so
# that they miss the edges and vertices of structured tubes; a length of its own, not a fraction
# of the cell: a coupon's rays must meet its yarns where the unit cell's do.
RAY_NUDGE = 1e-6


@dataclass(frozen=True)
class Cell:
    """The unit cell [x0, x0 + lx] x [y0, y0 + ly] in mm; z_range (zmin, zmax) clips if given.
    periodic: the cell repeats (its opposite sides are the same points); False for a coupon with
    free edges, whose sides are the yarns' cut ends."""

    lx: float
    ly: float
    x0: float = 0.0
    y0: float = 0.0
    z_range: tuple | None = None
    periodic: bool = True

    def __post_init__(self):
        object.__setattr__(self, "lx", limits.check_length("cell size lx", self.lx, limits.MAX_CELL))
        object.__setattr__(self, "ly", limits.check_length("cell size ly", self.ly, limits.MAX_CELL))
        for name in ("x0", "y0"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError, OverflowError):
                raise TextileError(f"cell origin {name} must be a number, got {value!r}") from None
            if not np.isfinite(value):
                raise TextileError(f"cell origin {name} must be finite, got {getattr(self, name)!r}")
            limits.check_coordinates(f"cell origin {name}", value)
            object.__setattr__(self, name, value)
        if self.z_range is not None:
            lo, hi = map(float, self.z_range)
            if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
                raise TextileError(f"cell z_range must be finite with zmax > zmin, got {self.z_range!r}")
            limits.check_coordinates("cell z_range", (lo, hi))
            object.__setattr__(self, "z_range", (lo, hi))
        if not isinstance(self.periodic, (bool, np.bool_)):
            raise TextileError(f"cell periodic must be true or false, got {self.periodic!r}")
        object.__setattr__(self, "periodic", bool(self.periodic))

    @property
    def repeats(self) -> np.ndarray:
        return np.array([[self.lx, 0.0, 0.0], [0.0, self.ly, 0.0]])

    @property
    def area(self) -> float:
        return self.lx * self.ly

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return self.x0, self.x0 + self.lx, self.y0, self.y0 + self.ly

    def grid(self, n: int) -> tuple[np.ndarray, float]:
        """Cell-centred n x n sample points (n*n, 2) and the area each represents."""
        x = self.x0 + (np.arange(n) + 0.5) * self.lx / n
        y = self.y0 + (np.arange(n) + 0.5) * self.ly / n
        X, Y = np.meshgrid(x, y, indexing="ij")
        return np.column_stack((X.ravel(), Y.ravel())), self.area / n**2


@dataclass(frozen=True)
class Resolution:
    """How finely yarn surfaces are discretised: station spacing along the yarn [mm], points
    per section polygon (64 points: section area within 0.16 % of the smooth curve) and the fewest
    stations between two master nodes (1 for a corrected yarn, whose master nodes are stations)."""

    spacing: float = 0.1
    section_points: int = 64
    per_segment: int = 4

    def __post_init__(self):
        limits.check_length("resolution spacing", self.spacing)
        limits.check_count("resolution section_points", self.section_points, limits.MIN_SECTION_POINTS,
                           limits.MAX_SECTION_POINTS)
        limits.check_count("resolution per_segment", self.per_segment, 1, 64)


@dataclass
class Columns:
    """Vertical-ray answers: one row per (point, yarn, interval), sorted by point then yarn then z.

    point: index of the query point; yarn: yarn index; bottom, top: z of the interval [mm].
    odd: number of (point, yarn) columns whose crossing count was odd (a ray grazing the surface);
    these keep their outermost crossings as one interval.
    """

    n_points: int
    point: np.ndarray
    yarn: np.ndarray
    bottom: np.ndarray
    top: np.ndarray
    odd: int = 0

    def envelope(self, n_yarns: int) -> tuple[np.ndarray, np.ndarray]:
        """(n_points, n_yarns) arrays of each yarn's lowest bottom and highest top (NaN: not over)."""
        bot = np.full((self.n_points, n_yarns), np.nan)
        top = np.full((self.n_points, n_yarns), np.nan)
        np.fmin.at(bot, (self.point, self.yarn), self.bottom)
        np.fmax.at(top, (self.point, self.yarn), self.top)
        return bot, top


@dataclass(eq=False)
class Textile:
    """A unit cell with its yarns (mm, z through the thickness). tiling: for a coupon made by
    `coupon.tile`, how (the unit cell, the repeats, each yarn's source), so that its mesh can be
    the unit cell's repeated; None otherwise. thickness: the thickness the fabric is woven to [mm],
    where its maker states one (a 3D weave's: TexGen's FabricThickness, our orthogonal builder's),
    the default mould of the solve (pipeline.Settings.mould); None otherwise."""

    cell: Cell
    yarns: list = field(default_factory=list)
    name: str = "textile"
    resolution: Resolution = field(default_factory=Resolution)
    tiling: object = None
    thickness: float | None = None

    def __post_init__(self):
        if not self.yarns:
            raise TextileError(f"textile {self.name!r} has no yarns")
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
        stations = sum(float(np.sum(np.maximum(np.ceil(np.linalg.norm(np.diff(y.nodes, axis=0), axis=1) / r.spacing), 4)))
                       for y in self.yarns)
        points = stations * r.section_points
        if points > limits.MAX_SURFACE_POINTS:
            raise TextileError(f"textile {self.name!r}: its yarn surfaces would have about {points:.3g} points "
                               f"(stations every {r.spacing:g} mm along {len(self.yarns)} yarns, {r.section_points} "
                               f"points per section), more than the limit of {limits.MAX_SURFACE_POINTS:.3g}; use a "
                               "larger resolution spacing or fewer section_points")

    def _check_closes(self, yarn: Yarn) -> None:
        """A periodic yarn must come back onto itself after whole cells: its last master node is
        its first moved by (a lx, b ly, 0) with whole a, b (else the pattern is not periodic)."""
        p, c = yarn.period, self.cell
        with np.errstate(over="ignore"):
            a, b = p[0] / c.lx, p[1] / c.ly
        tol = 1e-6
        if not (np.isfinite(a) and np.isfinite(b)) or abs(a - round(a)) > tol or abs(b - round(b)) > tol or abs(p[2]) > tol * max(c.lx, c.ly) \
                or (round(a), round(b)) == (0, 0):
            raise TextileError(f"{yarn.name}: not periodic over the cell: its last master node is its first "
                               f"moved by ({p[0]:g}, {p[1]:g}, {p[2]:g}) mm, which is not a whole number of "
                               f"cells ({c.lx:g} x {c.ly:g} mm, no rise); close the path or mark the yarn "
                               "non-periodic")

    # --- periodic copies --------------------------------------------------------------------
    def _translations(self, yarn: Yarn, bbox_lo: np.ndarray, bbox_hi: np.ndarray,
                      region: tuple | None = None) -> list[np.ndarray]:
        """Repeat translations of a yarn whose box (bbox of one period) meets the cell's box (or
        the region's (x0, x1, y0, y1))."""
        reps = yarn.repeats if len(yarn.repeats) else np.zeros((1, 3))
        x0, x1, y0, y1 = self.cell.bounds if region is None else region
        reach = []
        for r in reps:
            size = np.linalg.norm(r[:2])
            reach.append(range(-2, 3) if size > 0 else range(1))
        out = []
        for ks in product(*reach):
            t = np.sum([k * r for k, r in zip(ks, reps)], axis=0)
            lo, hi = bbox_lo + t, bbox_hi + t
            if lo[0] <= x1 and hi[0] >= x0 and lo[1] <= y1 and hi[1] >= y0:
                out.append(t)
        return out

    def triangles(self, i: int, region: tuple | None = None) -> np.ndarray:
        """Triangles (T, 3, 3) of yarn i's surface, periodic copies included, that vertical rays
        through `region` (x0, x1, y0, y1; default the cell) can hit: only those whose plan reaches
        it are kept (on a coupon, whole periodic copies of long yarns would cost gigabytes)."""
        x0, x1, y0, y1 = self.cell.bounds
        if region is not None:  # always the cell, and the region
            x0, x1, y0, y1 = min(x0, region[0]), max(x1, region[1]), min(y0, region[2]), max(y1, region[3])
        box, tris = self._triangles.get(i, (None, None))
        if box is None or box[0] > x0 or box[1] < x1 or box[2] > y0 or box[3] < y1:
            if box is not None:
                x0, x1, y0, y1 = min(x0, box[0]), max(x1, box[1]), min(y0, box[2]), max(y1, box[3])
            yarn = self.yarns[i]
            verts, _ = yarn.tube(self.resolution.spacing, self.resolution.section_points, self.resolution.per_segment)
            one = _tube_triangles(verts, closed_ends=not yarn.periodic)
            lo, hi = verts.reshape(-1, 3).min(axis=0), verts.reshape(-1, 3).max(axis=0)
            pad = 1e-6 * max(self.cell.lx, self.cell.ly)
            t_lo, t_hi = _plan_box(one)
            copies = []
            for t in self._translations(yarn, lo, hi, (x0, x1, y0, y1)):
                keep = ((t_hi[:, 0] + t[0] >= x0 - pad) & (t_lo[:, 0] + t[0] <= x1 + pad)
                        & (t_hi[:, 1] + t[1] >= y0 - pad) & (t_lo[:, 1] + t[1] <= y1 + pad))
                copies.append(one[keep] + t)
            tris = np.concatenate(copies) if copies else np.zeros((0, 3, 3))
            self._triangles[i] = ((x0, x1, y0, y1), tris)
        return tris

    def forget_surfaces(self) -> None:
        """Drop the cached yarn triangles (large on coupons) once the queries are done."""
        self._triangles = {}

    def __getstate__(self) -> dict:
        """Pickled without the cached triangles (tens of MB; rebuilt on the first query)."""
        return {**self.__dict__, "_triangles": {}}

    # --- queries ----------------------------------------------------------------------------
    def columns(self, xy, yarns=None) -> Columns:
        """Vertical-ray intervals of every yarn (or those listed) over in-plane points xy (N, 2)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        probe = xy + np.array([0.7548776662, 0.5698402910]) * RAY_NUDGE
        rows = []
        odd = 0
        region = (*(probe[:, 0].min(), probe[:, 0].max()), *(probe[:, 1].min(), probe[:, 1].max())) if len(probe) else None
        lattice = _lattice(probe) if len(probe) else None  # the same points for every yarn
        for i in range(len(self.yarns)) if yarns is None else yarns:
            pidx, z = _vertical_hits(self.triangles(i, region), probe, self.resolution.spacing, lattice)
            order = np.lexsort((z, pidx))
            pidx, z = pidx[order], z[order]
            starts = np.flatnonzero(np.r_[True, pidx[1:] != pidx[:-1]]) if len(pidx) else np.zeros(0, int)
            counts = np.diff(np.r_[starts, len(pidx)])
            rank = np.arange(len(pidx)) - np.repeat(starts, counts)
            even = np.repeat(counts % 2 == 0, counts)
            odd += int(np.sum(counts % 2 == 1))
            # even columns: crossings pair up in order; odd: the outermost crossings form one interval
            lo = even & (rank % 2 == 0)
            rows.append((pidx[lo], np.full(lo.sum(), i), z[lo], z[np.flatnonzero(lo) + 1]))
            first, last = starts[counts % 2 == 1], starts[counts % 2 == 1] + counts[counts % 2 == 1] - 1
            rows.append((pidx[first], np.full(len(first), i), z[first], z[last]))
        point, yarn, bottom, top = (np.concatenate(c) if rows else np.zeros(0) for c in zip(*rows))
        order = np.lexsort((bottom, yarn, point))
        return Columns(len(xy), point[order].astype(int), yarn[order].astype(int), bottom[order], top[order], odd)

    def inside(self, points) -> np.ndarray:
        """(N, n_yarns) booleans: is 3D point k inside yarn i."""
        points = np.asarray(points, float).reshape(-1, 3)
        col = self.columns(points[:, :2])
        z = points[col.point, 2]
        hit = (col.bottom <= z) & (z <= col.top)
        out = np.zeros((len(points), len(self.yarns)), bool)
        out[col.point[hit], col.yarn[hit]] = True
        return out

    def nearest_centreline(self, i: int, points) -> tuple[np.ndarray, np.ndarray]:
        """Positions and unit tangents (N, 3) of yarn i's centreline (periodic copies included) at
        the samples nearest to `points`: (N, 2) in-plane (nearest in plan) or (N, 3) positions."""
        points = np.asarray(points, float)
        dim = points.shape[-1]
        yarn = self.yarns[i]
        s = yarn.stations(self.resolution.spacing / 4)
        pos, tan = yarn.centreline(s)
        lo, hi = pos.min(axis=0), pos.max(axis=0)
        shifts = self._translations(yarn, lo, hi) or [np.zeros(3)]
        cloud = np.concatenate([pos + t for t in shifts])
        tangents = np.tile(tan, (len(shifts), 1))
        if len(points.reshape(-1, dim)) == 0:
            return np.zeros((0, 3)), np.zeros((0, 3))
        _, k = cKDTree(cloud[:, :dim]).query(points.reshape(-1, dim))
        return cloud[k], tangents[k]

    def fibre_direction(self, i: int, points) -> np.ndarray:
        """Unit fibre tangents (N, 3) of yarn i at the centreline points nearest to `points`
        ((N, 2) in-plane or (N, 3) positions)."""
        return self.nearest_centreline(i, points)[1]

    def tubes(self, i: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """Closed tubes (points, outward triangles) of yarn i that together cover the cell: a
        periodic yarn's copies along its own period are chained into one long capped tube per
        lateral shift (surfaces.YarnSurfaces clips them to the cell)."""
        yarn = self.yarns[i]
        verts, _ = yarn.tube(self.resolution.spacing, self.resolution.section_points, self.resolution.per_segment)
        lo, hi = verts.reshape(-1, 3).min(axis=0), verts.reshape(-1, 3).max(axis=0)
        if not yarn.periodic:  # a piece: its copies by the repeats (none with free edges)
            return [_closed_tube(verts + t) for t in self._translations(yarn, lo, hi)]
        P = yarn.period
        bases = {}
        for t in self._translations(yarn, lo, hi):
            k = int(np.round(t @ P / (P @ P)))
            b = t - k * P
            bases.setdefault(tuple(np.round(b, 9)), (b, []))[1].append(k)
        pieces = []
        for b, ks in bases.values():
            chain = [verts + k * P + b for k in range(min(ks) - 1, max(ks) + 2)]
            pieces.append(_closed_tube(np.concatenate([chain[0]] + [c[1:] for c in chain[1:]])))
        return pieces


def _tube_triangles(verts: np.ndarray, closed_ends: bool) -> np.ndarray:
    """Triangles (T, 3, 3) of a structured tube (M stations, K points around)."""
    pts, faces = _closed_tube(verts) if closed_ends else _open_tube(verts)
    return pts[faces]


def _open_tube(verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    M, K, _ = verts.shape
    idx = np.arange(M * K).reshape(M, K)
    a, b = idx[:-1], idx[1:]
    a1, b1 = np.roll(a, -1, axis=1), np.roll(b, -1, axis=1)
    faces = np.concatenate([np.stack((a, b, b1), -1).reshape(-1, 3), np.stack((a, b1, a1), -1).reshape(-1, 3)])
    return verts.reshape(-1, 3), faces


def _closed_tube(verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A tube capped at both ends by fans, oriented with outward normals."""
    M, K, _ = verts.shape
    pts, faces = _open_tube(verts)
    c0, c1 = len(pts), len(pts) + 1
    pts = np.vstack((pts, verts[0].mean(axis=0), verts[-1].mean(axis=0)))
    k = np.arange(K)
    cap0 = np.column_stack((np.full(K, c0), np.roll(k, -1), k))
    cap1 = np.column_stack((np.full(K, c1), (M - 1) * K + k, (M - 1) * K + np.roll(k, -1)))
    faces = np.vstack((faces, cap0, cap1))
    tri = pts[faces]
    signed = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    if signed < 0:
        faces = faces[:, ::-1]
    return pts, faces


def _vertical_hits(tris: np.ndarray, pts: np.ndarray, bin_size: float,
                   lattice: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Crossings of vertical lines through pts (N, 2) with triangles (T, 3, 3).

    Returns (point index, z) of every crossing. Triangles and points are matched through a uniform
    grid of bins so the work grows with the number of crossings, not points x triangles. The bins
    are `bin_size` (the surface's station spacing) or smaller where the triangles are much smaller
    (yarns with dense master nodes), and the candidate pairs are tested in chunks, so the memory
    stays bounded whatever the triangles' sizes. Points on a regular lattice (the metrics' grid, a
    cut along x or y; `lattice`, what _lattice found for them) need no bins: each triangle's
    candidates are the nodes in its bounding box (_lattice_hits; the same crossings, 3 x faster on
    a corrected satin's grid).
    """
    if len(tris) == 0 or len(pts) == 0:
        return np.zeros(0, int), np.zeros(0)
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    keep = np.abs(area2) > 1e-14 * bin_size**2
    tris, area2 = tris[keep], area2[keep]
    t_min, t_max = _plan_box(tris)
    if lattice is not None:
        return _lattice_hits(tris, area2, t_min, t_max, pts, *lattice)
    lo_p, hi_p = pts.min(axis=0), pts.max(axis=0)
    bin_size = _bin_size(t_max - t_min, len(pts), hi_p - lo_p, bin_size)
    nb = np.maximum(np.ceil((hi_p - lo_p) / bin_size).astype(np.int64), 1)
    pbin = np.minimum(((pts - lo_p) / bin_size).astype(np.int64), nb - 1)
    pid = pbin[:, 0] * nb[1] + pbin[:, 1]
    order = np.argsort(pid, kind="stable")
    spid = pid[order]
    tlo = np.floor((t_min - lo_p) / bin_size).astype(np.int64)
    thi = np.floor((t_max - lo_p) / bin_size).astype(np.int64)
    tlo, thi = np.maximum(tlo, 0), np.minimum(thi, nb - 1)
    ok = np.all(tlo <= thi, axis=1)
    tri_ids = np.flatnonzero(ok)
    tlo, span = tlo[ok], thi[ok] - tlo[ok] + 1
    counts = span[:, 0] * span[:, 1]
    rep = np.repeat(np.arange(len(tri_ids)), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    bid = (tlo[rep, 0] + local // span[rep, 1]) * nb[1] + tlo[rep, 1] + local % span[rep, 1]
    del local
    start = np.searchsorted(spid, bid, "left")
    n = np.searchsorted(spid, bid, "right") - start
    del bid
    hit_p, hit_z = [], []
    for first, last in _chunks(n):  # (triangle, bin) entries
        nn = n[first:last]
        t_of = tri_ids[np.repeat(rep[first:last], nn)]
        p_of = order[np.repeat(start[first:last], nn) + np.arange(nn.sum()) - np.repeat(np.cumsum(nn) - nn, nn)]
        T, p = tris[t_of], pts[p_of]
        inside, z = _crossing(T, p, area2[t_of])
        hit_p.append(p_of[inside])
        hit_z.append(z)
    if not hit_p:
        return np.zeros(0, int), np.zeros(0)
    return np.concatenate(hit_p), np.concatenate(hit_z)


def _chunks(counts: np.ndarray):
    """(first, last) slices of consecutive entries whose counts of candidate pairs add up to at
    most _CHUNK (one entry at least)."""
    ends = np.cumsum(counts)
    first = 0
    while first < len(counts):
        last = max(int(np.searchsorted(ends, (ends[first - 1] if first else 0) + _CHUNK, "right")), first + 1)
        yield first, last
        first = last


def _plan_box(tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners (T, 2) of the triangles' (T, 3, 3) plan bounding boxes (vertex by
    vertex: a reduction over the short middle axis is several times slower)."""
    a, b, c = tris[:, 0, :2], tris[:, 1, :2], tris[:, 2, :2]
    return np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)


def _crossing(T: np.ndarray, p: np.ndarray, area2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For candidate pairs (triangle T (K, 3, 3) with twice its signed plan area, plan point p
    (K, 2)): which vertical lines cross their triangle (barycentric coordinates all >= 0), and the
    z of those crossings."""
    A, B, C = T[:, 0], T[:, 1], T[:, 2]
    l1 = ((p[:, 0] - A[:, 0]) * (C[:, 1] - A[:, 1]) - (p[:, 1] - A[:, 1]) * (C[:, 0] - A[:, 0])) / area2
    l2 = ((B[:, 0] - A[:, 0]) * (p[:, 1] - A[:, 1]) - (B[:, 1] - A[:, 1]) * (p[:, 0] - A[:, 0])) / area2
    l0 = 1 - l1 - l2
    inside = (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
    return inside, l0[inside] * A[inside, 2] + l1[inside] * B[inside, 2] + l2[inside] * C[inside, 2]


def _lattice(pts: np.ndarray):
    """If the points (N, 2) are nodes of a regular axis-aligned lattice (a metrics grid, a rank's
    share of one, a cut along x or y), without repeats and filling at least a quarter of the nodes
    between their extremes: (origin (2,), steps (2,), shape (nx, ny), the point at each node or -1);
    else None."""
    origin, steps, shape, index = [], [], [], []
    for d in range(2):
        u = np.unique(pts[:, d])
        h = float(np.min(np.diff(u))) if len(u) > 1 else 1.0
        k = np.rint((pts[:, d] - u[0]) / h).astype(np.int64)
        if np.max(np.abs(u[0] + k * h - pts[:, d])) > 1e-9 * max(h, abs(u[0]), abs(u[-1])):
            return None
        origin.append(u[0]), steps.append(h), shape.append(int(k.max()) + 1), index.append(k)
    if shape[0] * shape[1] > 4 * len(pts):
        return None
    node = np.full(shape[0] * shape[1], -1, np.int64)
    flat = index[0] * shape[1] + index[1]
    node[flat] = np.arange(len(pts))
    if np.any(node[flat] != np.arange(len(pts))):  # a point given twice
        return None
    return np.array(origin), np.array(steps), tuple(shape), node


def _lattice_hits(tris, area2, t_min, t_max, pts, origin, steps, shape, node):
    """_vertical_hits for points on a lattice (_lattice): each triangle's candidates are the
    lattice nodes inside its plan's bounding box, found by arithmetic (no binning, no sort), in
    chunks of at most _CHUNK pairs."""
    lo = np.maximum(np.ceil((t_min - origin) / steps - 1e-9), 0).astype(np.int64)
    hi = np.minimum(np.floor((t_max - origin) / steps + 1e-9), np.array(shape) - 1).astype(np.int64)
    span = np.maximum(hi - lo + 1, 0)
    counts = span[:, 0] * span[:, 1]
    some = np.flatnonzero(counts)
    hit_p, hit_z = [], []
    for first, last in _chunks(counts[some]):
        tri, n = some[first:last], counts[some[first:last]]
        t_of = np.repeat(tri, n)
        local = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        i = lo[t_of, 0] + local // span[t_of, 1]
        j = lo[t_of, 1] + local % span[t_of, 1]
        p_of = node[i * shape[1] + j]
        t_of, p_of = t_of[p_of >= 0], p_of[p_of >= 0]
        T, p = tris[t_of], pts[p_of]
        inside, z = _crossing(T, p, area2[t_of])
        hit_p.append(p_of[inside])
        hit_z.append(z)
    if not hit_p:
        return np.zeros(0, int), np.zeros(0)
    return np.concatenate(hit_p), np.concatenate(hit_z)


# Candidate (triangle, point) pairs tested at once by _vertical_hits (about 100 bytes each).
_CHUNK = 2_000_000


def _bin_size(extent: np.ndarray, n_points: int, box: np.ndarray, largest: float) -> float:
    """The bin size, at most `largest`, that makes the fewest (triangle, bin) entries plus
    candidate pairs for triangles of these plan extents (T, 2) and points spread over `box`."""
    area = max(float(box[0]) * float(box[1]), (largest / 4) ** 2, 1e-300)
    density = n_points / area
    best, best_cost = largest, np.inf
    size = largest
    for _ in range(12):
        entries = float(np.sum((extent[:, 0] / size + 1) * (extent[:, 1] / size + 1)))
        cost = entries * (1 + density * size * size)
        if cost < best_cost:
            best, best_cost = size, cost
        size /= 2
        if np.max(box) / size > 1e7:  # keeps the bin indices small
            break
    return best
