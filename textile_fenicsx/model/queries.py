"""Geometric queries on a textile's yarn surfaces, vectorised over many points (DESIGN.md section 3).

Every yarn surface is a tube of section polygons at stations along its centreline (spacing and
points per section from the textile's `Resolution`), repeated by the yarn's repeat vectors. The
model (`Textile`) keeps the data and a cache of each yarn's triangles; these functions answer:
- `translations`: the periodic copies of a yarn that reach a box;
- `yarn_triangles`: the triangles of a yarn's surface, copies included, that rays over a region can hit;
- `columns`: vertical rays through in-plane points, every yarn interval over each (rays.py);
- `inside`: which yarns contain 3D points; `nearest_centreline`: the nearest centreline samples;
- `tubes`: closed tubes of a yarn that together cover the cell.
`Textile.columns`, `.inside`, `.nearest_centreline`, `.fibre_direction`, `.tubes` and `.triangles`
call them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from itertools import product
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from textile_fenicsx.model.cell import Cell, Resolution
from textile_fenicsx.model.rays import TriangleBins, lattice, plan_box, vertical_hits
from textile_fenicsx.model.yarn import Yarn

__all__ = ["RAY_NUDGE", "Columns", "closed_tube", "columns", "inside", "nearest_centreline", "translations", "tubes",
           "yarn_triangles"]



class Textile(Protocol):
    """What the queries read of a textile (model.textile.Textile is one; that module calls these
    functions from its methods, so the type is stated here rather than imported)."""

    @property
    def cell(self) -> Cell: ...

    @property
    def yarns(self) -> list[Yarn]: ...

    @property
    def resolution(self) -> Resolution: ...

    def columns(self, xy: ArrayLike, yarns: Iterable[int] | None = None) -> Columns: ...

    def triangles(self, i: int, region: tuple | None = None) -> np.ndarray: ...


# Vertical rays are nudged off the query points by this much [mm] (a fixed irrational direction), so
# that they miss the edges and vertices of structured tubes; a length of its own, not a fraction
# of the cell: a coupon's rays must meet its yarns where the unit cell's do.
RAY_NUDGE = 1e-6


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


def translations(textile: Textile, yarn: Yarn, bbox_lo: np.ndarray, bbox_hi: np.ndarray,
                 region: tuple | None = None) -> list[np.ndarray]:
    """Repeat translations of a yarn whose box (bbox of one period) meets the cell's box (or the
    region's (x0, x1, y0, y1))."""
    reps = yarn.repeats if len(yarn.repeats) else np.zeros((1, 3))
    x0, x1, y0, y1 = textile.cell.bounds if region is None else region
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


def yarn_triangles(textile: Textile, i: int, region: tuple | None, cache: dict) -> np.ndarray:
    """Triangles (T, 3, 3) of yarn i's surface, periodic copies included, that vertical rays
    through `region` (x0, x1, y0, y1; default the cell) can hit: only those whose plan reaches it
    are kept (on a coupon, whole periodic copies of long yarns would cost gigabytes). `cache`
    (the model's) keeps, per yarn, the box covered so far and its triangles."""
    x0, x1, y0, y1 = textile.cell.bounds
    if region is not None:  # always the cell, and the region
        x0, x1, y0, y1 = min(x0, region[0]), max(x1, region[1]), min(y0, region[2]), max(y1, region[3])
    box, tris = cache.get(i, (None, None))
    if box is None or box[0] > x0 or box[1] < x1 or box[2] > y0 or box[3] < y1:
        if box is not None:
            x0, x1, y0, y1 = min(x0, box[0]), max(x1, box[1]), min(y0, box[2]), max(y1, box[3])
        yarn = textile.yarns[i]
        r = textile.resolution
        verts, _ = yarn.tube(r.spacing, r.section_points, r.per_segment)
        one = _tube_triangles(verts, closed_ends=not yarn.periodic)
        lo, hi = verts.reshape(-1, 3).min(axis=0), verts.reshape(-1, 3).max(axis=0)
        pad = 1e-6 * max(textile.cell.lx, textile.cell.ly)
        t_lo, t_hi = plan_box(one)
        copies = []
        for t in translations(textile, yarn, lo, hi, (x0, x1, y0, y1)):
            keep = ((t_hi[:, 0] + t[0] >= x0 - pad) & (t_lo[:, 0] + t[0] <= x1 + pad)
                    & (t_hi[:, 1] + t[1] >= y0 - pad) & (t_lo[:, 1] + t[1] <= y1 + pad))
            copies.append(one[keep] + t)
        tris = np.concatenate(copies) if copies else np.zeros((0, 3, 3))
        cache[i] = ((x0, x1, y0, y1), tris)
    return tris


def columns(textile: Textile, xy: ArrayLike, yarns: Iterable[int] | None = None,
            bins: dict[int, TriangleBins] | None = None) -> Columns:
    """Vertical-ray intervals of every yarn (or those listed) over in-plane points xy (N, 2).
    bins: for a caller that asks about a few points at a time, again and again, of the same
    model (metrics._deepest): each yarn's triangles binned once (rays.TriangleBins), kept in
    this dict between the calls (the same answers)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    probe = xy + np.array([0.7548776662, 0.5698402910]) * RAY_NUDGE
    rows = []
    odd = 0
    region = (*(probe[:, 0].min(), probe[:, 0].max()), *(probe[:, 1].min(), probe[:, 1].max())) if len(probe) else None
    grid = lattice(probe) if len(probe) and bins is None else None  # the same points for every yarn
    for i in range(len(textile.yarns)) if yarns is None else yarns:
        tris = textile.triangles(i, region)
        if bins is None:
            pidx, z = vertical_hits(tris, probe, textile.resolution.spacing, grid)
        else:
            if i not in bins or bins[i].source is not tris:
                bins[i] = TriangleBins(tris, textile.resolution.spacing)
            pidx, z = bins[i].hits(probe)
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


def inside(textile: Textile, points: ArrayLike) -> np.ndarray:
    """(N, n_yarns) booleans: is 3D point k inside yarn i."""
    points = np.asarray(points, float).reshape(-1, 3)
    col = textile.columns(points[:, :2])
    z = points[col.point, 2]
    hit = (col.bottom <= z) & (z <= col.top)
    out = np.zeros((len(points), len(textile.yarns)), bool)
    out[col.point[hit], col.yarn[hit]] = True
    return out


TURN_PER_SAMPLE = np.radians(1.0)
"""The most a yarn's tangent turns between the centreline samples that give 3D points their fibre
direction [rad]."""


def nearest_centreline(textile: Textile, i: int, points: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Positions and unit tangents (N, 3) of yarn i's centreline (periodic copies included) at the
    samples nearest to `points`: (N, 2) in-plane (nearest in plan) or (N, 3) positions. The samples
    are a quarter of the model's spacing apart, and for 3D positions (the fibre directions of volume
    meshes) also at most TURN_PER_SAMPLE apart in direction: a binder turning round a 0.1 mm radius
    would otherwise be off by up to 8 degrees between its samples."""
    points = np.asarray(points, float)
    dim = points.shape[-1]
    yarn = textile.yarns[i]
    s = yarn.stations(textile.resolution.spacing / 4, turn=TURN_PER_SAMPLE if dim == 3 else np.inf)
    pos, tan = yarn.centreline(s)
    points = points.reshape(-1, dim)
    if len(points) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    shifts = translations(textile, yarn, lo, hi, _reaching(textile, yarn, s, points)) or [np.zeros(3)]
    cloud = np.concatenate([pos + t for t in shifts])
    tangents = np.tile(tan, (len(shifts), 1))
    _, k = cKDTree(cloud[:, :dim]).query(points)
    return cloud[k], tangents[k]


def _reaching(textile: Textile, yarn: Yarn, s: np.ndarray, points: np.ndarray) -> tuple:
    """The plan region (x0, x1, y0, y1) whose copies of the yarn can hold the points nearest: the
    cell's, widened on each side the points lie beyond by the yarn's largest section radius (a box
    moved off the cell's origin has elements in copies whose centrelines never meet the cell)."""
    x0, x1, y0, y1 = textile.cell.bounds
    (a0, b0), (a1, b1) = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    if a0 >= x0 and a1 <= x1 and b0 >= y0 and b1 <= y1:
        return x0, x1, y0, y1
    r = float(np.linalg.norm(yarn.section_points(s, 16), axis=2).max())
    return (x0 if a0 >= x0 else a0 - r, x1 if a1 <= x1 else a1 + r,
            y0 if b0 >= y0 else b0 - r, y1 if b1 <= y1 else b1 + r)


def tubes(textile: Textile, i: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Closed tubes (points, outward triangles) of yarn i that together cover the cell: a periodic
    yarn's copies along its own period are chained into one long capped tube per lateral shift
    (surfaces.YarnSurfaces clips them to the cell)."""
    yarn = textile.yarns[i]
    r = textile.resolution
    verts, _ = yarn.tube(r.spacing, r.section_points, r.per_segment)
    lo, hi = verts.reshape(-1, 3).min(axis=0), verts.reshape(-1, 3).max(axis=0)
    if not yarn.periodic:  # a piece: its copies by the repeats (none with free edges)
        return [closed_tube(verts + t) for t in translations(textile, yarn, lo, hi)]
    P = yarn.period
    bases: dict[tuple, tuple[np.ndarray, list[int]]] = {}
    for t in translations(textile, yarn, lo, hi):
        k = int(np.round(t @ P / (P @ P)))
        b = t - k * P
        bases.setdefault(tuple(np.round(b, 9)), (b, []))[1].append(k)
    pieces = []
    for b, ks in bases.values():
        chain = [verts + k * P + b for k in range(min(ks) - 1, max(ks) + 2)]
        pieces.append(closed_tube(np.concatenate([chain[0]] + [c[1:] for c in chain[1:]])))
    return pieces


def _tube_triangles(verts: np.ndarray, closed_ends: bool) -> np.ndarray:
    """Triangles (T, 3, 3) of a structured tube (M stations, K points around)."""
    pts, faces = closed_tube(verts) if closed_ends else _open_tube(verts)
    return pts[faces]


def _open_tube(verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    M, K, _ = verts.shape
    idx = np.arange(M * K).reshape(M, K)
    a, b = idx[:-1], idx[1:]
    a1, b1 = np.roll(a, -1, axis=1), np.roll(b, -1, axis=1)
    faces = np.concatenate([np.stack((a, b, b1), -1).reshape(-1, 3), np.stack((a, b1, a1), -1).reshape(-1, 3)])
    return verts.reshape(-1, 3), faces


def closed_tube(verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


