"""Footprints: each yarn's outline seen along z (DESIGN.md section 4, step 1).

The outline of a yarn comes from the lateral extremes of its sections at stations along it, one
(right, left) pair of side chains per lateral copy of the yarn that reaches the cell, chained over
neighbouring periods so that it covers the cell along the yarn; the projected mesh clips them to
the cell. `footprint_area` measures the part inside the cell, independently of any mesh.
"""

from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from textile_fenicsx.model.queries import translations
from textile_fenicsx.model.textile import Cell, Textile

__all__ = ["footprint_area", "footprint_outlines", "snap_to_neighbours"]


def footprint_outlines(textile: Textile, i: int, spacing: float,
                       pad: float = 0.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Outlines of yarn i seen along z: one (right, left) pair of side chains ((n, 2) each, in the
    yarn's direction) per lateral copy that reaches the cell grown by `pad`, long enough to cover
    the cell along the yarn (several periods chained). The closed outline is right + reversed left."""
    yarn = textile.yarns[i]
    s = yarn.stations(spacing)
    pos, _, up, side = yarn.frames(s)
    sec = yarn.section_points(s, textile.resolution.section_points)
    pts = pos[:, None, :2] + sec[..., :1] * side[:, None, :2] + sec[..., 1:] * up[:, None, :2]
    # Lateral direction: the in-plane normal of the yarn's overall direction.
    axis = yarn.period[:2] if yarn.periodic else (yarn.nodes[-1] - yarn.nodes[0])[:2]
    axis = axis / np.linalg.norm(axis)
    normal = np.array([-axis[1], axis[0]])
    lateral = np.einsum("mkj,j->mk", pts - pos[:, None, :2], normal)
    m = np.arange(len(s))
    left, right = pts[m, np.argmax(lateral, axis=1)], pts[m, np.argmin(lateral, axis=1)]
    lo, hi = pts.reshape(-1, 2).min(axis=0), pts.reshape(-1, 2).max(axis=0)
    x0, x1, y0, y1 = textile.cell.bounds
    region = (x0 - pad, x1 + pad, y0 - pad, y1 + pad)
    if not yarn.periodic:  # a piece (free edges, or a crown of a cut yarn): its copies by the repeats
        return [(right + t[:2], left + t[:2]) for t in translations(textile, yarn, np.r_[lo, 0], np.r_[hi, 0], region)]
    P = yarn.period[:2]
    outlines: dict[tuple, tuple[np.ndarray, list[int]]] = {}
    for t in translations(textile, yarn, np.r_[lo, 0], np.r_[hi, 0], region):
        k = int(np.round(t[:2] @ P / (P @ P)))
        b = t[:2] - k * P
        outlines.setdefault(tuple(np.round(b, 9)), (b, []))[1].append(k)
    result = []
    for b, found in outlines.values():
        ks = range(min(found) - 1, max(found) + 2)
        R = np.concatenate([right[(1 if n else 0):] + k * P + b for n, k in enumerate(ks)])
        L = np.concatenate([left[(1 if n else 0):] + k * P + b for n, k in enumerate(ks)])
        result.append((R, L))
    return result


def snap_to_neighbours(outlines: list[tuple[int, list[tuple[np.ndarray, np.ndarray]]]], tol: float,
                       cell: Cell) -> list[tuple[int, list[tuple[np.ndarray, np.ndarray]]]]:
    """The outlines [(yarn, [(right, left), ...]), ...] with every side chain that stays within
    `tol` of an earlier yarn's chain (or of a periodic copy of it) wherever it is over the cell
    replaced by that chain: two yarn edges that close are one edge. OpenCASCADE does not merge two
    edges that leave each other at a tiny angle: the wedge between them has a corner of no angle,
    which gmsh cannot mesh. TexGen's refined orthogonal weave has them in every weft column: an
    outer weft whose width changes between nodes (2.58 to 2.64 mm) by a ramped blend leaves the
    middle weft's edge tangentially."""
    x0, x1, y0, y1 = cell.bounds
    origin = np.array([x0, y0])
    period = np.array([cell.lx, cell.ly]) if cell.periodic else None
    lattice = replace(cell, x0=0.0, y0=0.0) if cell.shift else None  # about the origin, as the points
    out = []
    done: list[np.ndarray] = []  # the chains of the yarns done so far
    for i, sides in outlines:
        if done:
            owner = np.concatenate([np.full(len(c), k) for k, c in enumerate(done)])
            near = _Near(np.vstack(done) - origin, period, lattice)
            sides = [(_same_as(r, near, owner, done, tol, cell), _same_as(l_, near, owner, done, tol, cell))
                     for r, l_ in sides]
        out.append((i, sides))
        done += [c for pair in sides for c in pair]
    return out


class _Near:
    """The nearest points (NEIGHBOURS of them), across the periodic copies of the cell when it has a
    period."""

    NEIGHBOURS = 8

    def __init__(self, points: np.ndarray, period: np.ndarray | None, lattice: Cell | None = None) -> None:
        self.period, self.lattice, self.n = period, lattice, len(points)
        if lattice is not None:  # a sheared cell: scipy's periodic box is rectangular, so the points'
            # copies in the 8 cells around are in the tree (a point, moved into the cell, finds its
            # nearest within tol among them; tol is far below a cell)
            wrapped = lattice.wrap(points)
            self.tree = cKDTree(np.concatenate([wrapped + t for t in lattice.neighbours()]))
        else:
            self.tree = cKDTree(self._wrapped(points), boxsize=period if period is not None else None)

    def _wrapped(self, p: np.ndarray) -> np.ndarray:
        """p moved into the box [0, period) (np.mod returns the period itself for a point a round-off
        below a cell side, which scipy's periodic tree refuses)."""
        if self.lattice is not None:
            return self.lattice.wrap(p)
        if self.period is None:
            return p
        m = np.mod(p, self.period)
        return np.where(m >= self.period, m - self.period, m)

    def translation(self, d: np.ndarray) -> np.ndarray:
        """The whole cells nearest the in-plane move d (2,)."""
        if self.lattice is not None:
            return self.lattice.nearest_translation(d)[0]
        assert self.period is not None
        return np.round(d / self.period) * self.period

    def query(self, p: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
        """(distances, indices), each (len(p), NEIGHBOURS), nearest first; inf and n past tol."""
        k = min(self.NEIGHBOURS, self.tree.n)
        dist, idx = self.tree.query(self._wrapped(p), k=k,
                                    distance_upper_bound=tol)
        dist, idx = np.asarray(dist).reshape(len(p), k), np.asarray(idx).reshape(len(p), k)
        if self.lattice is not None:  # a copy's index is its point's; past tol stays n
            idx = np.where(idx < self.tree.n, idx % self.n, self.n)
        return dist, idx


def _same_as(chain: np.ndarray, near: _Near, owner: np.ndarray, chains: list[np.ndarray], tol: float,
             cell: Cell) -> np.ndarray:
    """The chain, or the earlier chain (moved by a whole number of cells) that every point of it
    over the cell lies within tol of, but not all on it. A chain over the cell at one point at most
    (a crown's copy whose end meets a side) is left as it is: it is no edge there."""
    x0, x1, y0, y1 = cell.bounds
    inside = (chain[:, 0] > x0) & (chain[:, 0] < x1) & (chain[:, 1] > y0) & (chain[:, 1] < y1)
    if np.count_nonzero(inside) < 2:
        return chain
    dist, nearest = near.query(chain[inside] - np.array([x0, y0]), tol)
    owners = np.where(np.isfinite(dist), owner[np.minimum(nearest, len(owner) - 1)], -1)
    for c in np.unique(owners[0][owners[0] >= 0]):
        hits = owners == c
        if not np.all(np.any(hits, axis=1)):
            continue
        if np.all(np.where(hits, dist, np.inf).min(axis=1) == 0):
            return chain  # the same edge already
        other = chains[c]
        shift = np.zeros(2)  # the copy of that chain over this one (chains run over several cells)
        if near.period is not None:
            shift = near.translation(np.median(chain, axis=0) - np.median(other, axis=0))
        d, _ = cKDTree(other + shift).query(chain[inside], distance_upper_bound=tol)
        if np.all(d < tol):
            return other + shift
    return chain


def _clip_to_box(poly: np.ndarray, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    """Sutherland-Hodgman: the part of polygon poly (n, 2) inside the box (convex clip window)."""
    for axis, value, keep_above in ((0, x0, True), (0, x1, False), (1, y0, True), (1, y1, False)):
        if len(poly) == 0:
            break
        inside = poly[:, axis] >= value if keep_above else poly[:, axis] <= value
        nxt = np.roll(poly, -1, axis=0)
        nxt_in = np.roll(inside, -1)
        out = []
        for p, q, pin, qin in zip(poly, nxt, inside, nxt_in):
            if pin:
                out.append(p)
            if pin != qin:
                f = (value - p[axis]) / (q[axis] - p[axis])
                out.append(p + f * (q - p))
        poly = np.array(out).reshape(-1, 2)
    return poly


def footprint_area(textile: Textile, i: int, spacing: float = 0.02) -> float:
    """Area [mm^2] of yarn i seen along z within the cell, from its section extremes at stations
    `spacing` apart (independent of any mesh)."""
    area = 0.0
    for right, left in footprint_outlines(textile, i, spacing):
        clipped = _clip_to_box(np.vstack((right, left[::-1])), *textile.cell.bounds)
        if len(clipped) >= 3:
            x, y = clipped[:, 0], clipped[:, 1]
            area += 0.5 * abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return float(area)


