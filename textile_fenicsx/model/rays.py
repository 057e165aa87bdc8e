"""Vertical rays through triangle soups: where lines parallel to z through in-plane points cross
triangles (T, 3, 3), as (point index, z) pairs. Pure numpy, no textile: the yarn-surface queries
(queries.py) call it with a yarn's triangles.

Triangles and points are matched through a uniform grid of bins (`vertical_hits`), or, for points
on a regular lattice (`lattice` finds one), through the lattice's own arithmetic (_lattice_hits);
both test the same pairs with the same arithmetic, in chunks of bounded memory.
"""

from collections.abc import Iterable, Iterator

import numpy as np

__all__ = ["TriangleBins", "lattice", "plan_box", "vertical_hits"]


def vertical_hits(tris: np.ndarray, pts: np.ndarray, bin_size: float,
                  grid: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Crossings of vertical lines through pts (N, 2) with triangles (T, 3, 3).

    Returns (point index, z) of every crossing. Triangles and points are matched through a uniform
    grid of bins so the work grows with the number of crossings, not points x triangles. The bins
    are `bin_size` (the surface's station spacing) or smaller where the triangles are much smaller
    (yarns with dense master nodes), and the candidate pairs are tested in chunks, so the memory
    stays bounded whatever the triangles' sizes. Points on a regular lattice (the metrics' grid, a
    cut along x or y; `grid`, what `lattice` found for them) need no bins: each triangle's
    candidates are the nodes in its bounding box (_lattice_hits; the same crossings, 3 x faster on
    a corrected satin's grid).
    """
    if len(tris) == 0 or len(pts) == 0:
        return np.zeros(0, int), np.zeros(0)
    tris, area2 = _in_plan(tris, bin_size)
    t_min, t_max = plan_box(tris)
    if grid is not None:
        return _lattice_hits(tris, area2, t_min, t_max, pts, *grid)
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

    def candidates() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for first, last in _chunks(n):  # (triangle, bin) entries
            nn = n[first:last]
            t_of = tri_ids[np.repeat(rep[first:last], nn)]
            p_of = order[np.repeat(start[first:last], nn) + np.arange(nn.sum()) - np.repeat(np.cumsum(nn) - nn, nn)]
            yield t_of, p_of

    return _hits(tris, area2, pts, candidates())


class TriangleBins:
    """Triangles (T, 3, 3) binned once in plan (square bins of `bin_size`), for vertical rays
    through a few points at a time: `hits(pts)` is vertical_hits(tris, pts, bin_size), whose every
    call bins all the triangles again (5-9 ms a yarn and call on satin4 at seed 0.25, some 15 000
    triangles a yarn, in the metrics' search around the deepest overlaps: 256 points, 6 rounds).
    The same crossings: a point's candidates are the triangles whose bins hold its bin, among them
    every triangle whose plan box holds the point, tested with the same arithmetic (_crossing)."""

    def __init__(self, tris: np.ndarray, bin_size: float):
        self.source = tris  # what it was built from (queries.columns builds it again if that changed)
        self.tris, self.area2 = _in_plan(tris, bin_size)
        self.size = bin_size
        t_min, t_max = plan_box(self.tris)
        self.origin = t_min.min(axis=0) if len(t_min) else np.zeros(2)
        lo = np.floor((t_min - self.origin) / bin_size).astype(np.int64)
        hi = np.floor((t_max - self.origin) / bin_size).astype(np.int64)
        self.shape = hi.max(axis=0) + 1 if len(hi) else np.ones(2, np.int64)
        span = hi - lo + 1
        counts = span[:, 0] * span[:, 1]
        rep = np.repeat(np.arange(len(lo)), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        bid = (lo[rep, 0] + local // span[rep, 1]) * self.shape[1] + lo[rep, 1] + local % span[rep, 1]
        order = np.argsort(bid)  # (the order within a bin does not matter)
        self.bin, self.tri = bid[order], rep[order]  # (triangle, bin) entries sorted by bin

    def hits(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(point index, z) of every crossing of the vertical lines through pts (N, 2)."""
        if len(self.tris) == 0 or len(pts) == 0:
            return np.zeros(0, int), np.zeros(0)
        cell = np.floor((pts - self.origin) / self.size).astype(np.int64)
        mine = np.flatnonzero(np.all((cell >= 0) & (cell < self.shape), axis=1))  # others: in no box
        bid = cell[mine, 0] * self.shape[1] + cell[mine, 1]
        start = np.searchsorted(self.bin, bid, "left")
        n = np.searchsorted(self.bin, bid, "right") - start

        def candidates() -> Iterator[tuple[np.ndarray, np.ndarray]]:
            for first, last in _chunks(n):  # points
                nn = n[first:last]
                at = np.repeat(start[first:last], nn) + np.arange(nn.sum()) - np.repeat(np.cumsum(nn) - nn, nn)
                yield self.tri[at], np.repeat(mine[first:last], nn)

        return _hits(self.tris, self.area2, pts, candidates())


def _in_plan(tris: np.ndarray, bin_size: float) -> tuple[np.ndarray, np.ndarray]:
    """The triangles whose plan is not degenerate (a vertical line cannot cross the others), with
    twice their signed plan areas."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    keep = np.abs(area2) > 1e-14 * bin_size**2
    return tris[keep], area2[keep]


def _hits(tris: np.ndarray, area2: np.ndarray, pts: np.ndarray,
          candidates: Iterable[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """(point index, z) of the crossings among chunks of candidate (triangle, point) index pairs."""
    hit_p, hit_z = [], []
    for t_of, p_of in candidates:
        T, p = tris[t_of], pts[p_of]
        inside, z = _crossing(T, p, area2[t_of])
        hit_p.append(p_of[inside])
        hit_z.append(z)
    if not hit_p:
        return np.zeros(0, int), np.zeros(0)
    return np.concatenate(hit_p), np.concatenate(hit_z)


def _chunks(counts: np.ndarray) -> Iterator[tuple[int, int]]:
    """(first, last) slices of consecutive entries whose counts of candidate pairs add up to at
    most _CHUNK (one entry at least)."""
    ends = np.cumsum(counts)
    first = 0
    while first < len(counts):
        last = max(int(np.searchsorted(ends, (ends[first - 1] if first else 0) + _CHUNK, "right")), first + 1)
        yield first, last
        first = last


def plan_box(tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def lattice(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[int, int], np.ndarray] | None:
    """If the points (N, 2) are nodes of a regular axis-aligned lattice (a metrics grid, a rank's
    share of one, a cut along x or y), without repeats and filling at least a quarter of the nodes
    between their extremes: (origin (2,), steps (2,), shape (nx, ny), the point at each node or -1);
    else None."""
    origin, steps, shape, index = [], [], [], []
    for d in range(2):
        u = np.unique(pts[:, d])
        h = float(np.min(np.diff(u))) if len(u) > 1 else 1.0
        if h <= 1e-12 * max(1.0, abs(u[0]), abs(u[-1])):  # two coordinates all but equal: no lattice
            return None
        k = np.rint((pts[:, d] - u[0]) / h).astype(np.int64)
        if np.max(np.abs(u[0] + k * h - pts[:, d])) > 1e-9 * max(h, abs(u[0]), abs(u[-1])):
            return None
        origin.append(u[0])
        steps.append(h)
        shape.append(int(k.max()) + 1)
        index.append(k)
    if shape[0] * shape[1] > 4 * len(pts):
        return None
    node = np.full(shape[0] * shape[1], -1, np.int64)
    flat = index[0] * shape[1] + index[1]
    node[flat] = np.arange(len(pts))
    if np.any(node[flat] != np.arange(len(pts))):  # a point given twice
        return None
    return np.array(origin), np.array(steps), (shape[0], shape[1]), node


def _lattice_hits(tris: np.ndarray, area2: np.ndarray, t_min: np.ndarray, t_max: np.ndarray, pts: np.ndarray,
                  origin: np.ndarray, steps: np.ndarray, shape: tuple[int, int],
                  node: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """vertical_hits for points on a lattice (`lattice`): each triangle's candidates are the
    lattice nodes inside its plan's bounding box, found by arithmetic (no binning, no sort), in
    chunks of at most _CHUNK pairs."""
    lo = np.maximum(np.ceil((t_min - origin) / steps - 1e-9), 0).astype(np.int64)
    hi = np.minimum(np.floor((t_max - origin) / steps + 1e-9), np.array(shape) - 1).astype(np.int64)
    span = np.maximum(hi - lo + 1, 0)
    counts = span[:, 0] * span[:, 1]
    some = np.flatnonzero(counts)

    def candidates() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for first, last in _chunks(counts[some]):
            tri, n = some[first:last], counts[some[first:last]]
            t_of = np.repeat(tri, n)
            local = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
            i = lo[t_of, 0] + local // span[t_of, 1]
            j = lo[t_of, 1] + local % span[t_of, 1]
            p_of = node[i * shape[1] + j]
            yield t_of[p_of >= 0], p_of[p_of >= 0]

    return _hits(tris, area2, pts, candidates())


# Candidate (triangle, point) pairs tested at once by vertical_hits (about 100 bytes each).
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


