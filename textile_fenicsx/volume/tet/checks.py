"""Checks of a tet mesh and of the model it is made from (mesher.py): pure numpy.

- `yarn_gaps`: the least vertical gap between any two yarns over a grid of the cell (negative: an
  overlap), with the pair and the place, measured by the model's vertical rays;
- `surface_crossings`: where triangles of a surface mesh cross each other, which gmsh's 3D mesher
  refuses as "a segment and a facet intersect" (two yarns' skins that cross in the gap between
  them: a spline through too few points of a cornered section overshoots);
- `enclosed_volume`: what a yarn's surface mesh encloses, which its tets will hold (before the
  3D mesh is made);
- `signed_volumes`, `phase_mismatch`, `fibre_angles`: inverted tets, elements whose centroid is
  not in their own yarn, fibre directions against the path tangent.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from textile_fenicsx.model.textile import Textile


def yarn_gaps(textile: Textile, n: int = 200) -> dict:
    """The least vertical gap between two different yarns over an n x n grid of the cell [mm]
    (negative: the deepest overlap) and where: {"gap", "pair" (i, j), "at" (x, y, z) mm}; gap is
    inf where no two yarns are ever over one another."""
    xy, _ = textile.cell.grid(n)
    col = textile.columns(xy)
    order = np.lexsort((col.bottom, col.point))
    pt, yarn, bot, top = col.point[order], col.yarn[order], col.bottom[order], col.top[order]
    best: dict[str, Any] = {"gap": float("inf"), "pair": None, "at": None}
    if len(pt) < 2:
        return best
    # every interval against every later one of the same point (a few per point)
    for shift in range(1, int(np.bincount(pt).max())):
        a, b = np.arange(len(pt) - shift), np.arange(shift, len(pt))
        same = (pt[a] == pt[b]) & (yarn[a] != yarn[b])
        a, b = a[same], b[same]
        if not len(a):
            continue
        # b starts at or above a's start: the gap is b's bottom less a's top (overlap: negative,
        # as deep as the shorter of the two common lengths)
        gap = np.maximum(bot[b] - top[a], -(np.minimum(top[a], top[b]) - bot[b]))
        k = int(np.argmin(gap))
        if gap[k] < best["gap"]:
            p = pt[a[k]]
            z = 0.5 * (top[a[k]] + bot[b[k]])
            best = {"gap": float(gap[k]), "pair": (int(yarn[a[k]]), int(yarn[b[k]])),
                    "at": (float(xy[p, 0]), float(xy[p, 1]), float(z))}
    return best


def _candidate_pairs(centre: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Pairs (P, 2), a < b, of triangles whose bounding spheres (centre, radius) meet: the
    triangles sorted into classes of radius within a factor 2, each class pair searched with
    one k-d tree query at the sum of the two classes' largest radii."""
    rank = np.floor(np.log2(np.maximum(radius, 1e-300) / radius.max())).astype(int)
    classes = [np.flatnonzero(rank == r) for r in np.unique(rank)]
    trees = [cKDTree(centre[k]) for k in classes]
    found = []
    for a, (ka, ta) in enumerate(zip(classes, trees)):
        for kb, tb in zip(classes[a:], trees[a:]):
            pairs = ta.sparse_distance_matrix(tb, radius[ka].max() + radius[kb].max(), output_type="ndarray")
            i, j = ka[pairs["i"]], kb[pairs["j"]]
            meet = np.linalg.norm(centre[i] - centre[j], axis=1) <= radius[i] + radius[j]
            found.append(np.stack([np.minimum(i, j), np.maximum(i, j)], axis=1)[meet & (i != j)])
    return np.unique(np.concatenate(found), axis=0) if found else np.zeros((0, 2), int)


def surface_crossings(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where an edge of one triangle of a surface mesh passes through another triangle that shares
    no node with it (a mesh that no conforming volume mesh can fill): the points [mm] (K, 3) and
    the two triangles (K, 2). points (N, 3); triangles (T, 3) node indices."""
    corner = points[triangles]
    centre = corner.mean(axis=1)
    radius = np.linalg.norm(corner - centre[:, None], axis=2).max(axis=1)
    pairs = _candidate_pairs(centre, radius)
    shared = (triangles[pairs[:, 0], :, None] == triangles[pairs[:, 1], None, :]).any(axis=(1, 2))
    pairs = pairs[~shared]
    hits, which = [], []
    for e, f in (pairs.T, pairs[:, ::-1].T):
        a, b, c = (corner[f, k] for k in range(3))
        n = np.cross(b - a, c - a)
        for k in range(3):  # the edge p -> q of triangle e against the plane of triangle f
            p, q = corner[e, k], corner[e, (k + 1) % 3]
            dp, dq = np.einsum("ij,ij->i", p - a, n), np.einsum("ij,ij->i", q - a, n)
            cross = dp * dq < 0
            x = p + (q - p) * (dp / np.where(cross, dp - dq, 1.0))[:, None]
            inside = cross.copy()
            for u, v in ((a, b), (b, c), (c, a)):
                inside &= np.einsum("ij,ij->i", np.cross(v - u, x - u), n) >= 0
            hits.append(x[inside])
            which.append(np.stack([e, f], axis=1)[inside])
    return np.concatenate(hits), np.concatenate(which)


def enclosed_volume(points: np.ndarray, faces: list[np.ndarray]) -> float:
    """The volume [mm^3] that one closed, connected surface encloses: faces, each its triangles
    (T, 3) (node rows of points (N, 3)) turning the same way within the face, but not necessarily
    as the others do (gmsh's copies on a periodic face turn against their face). The faces are
    turned to agree where they meet (an edge that two faces share runs opposite ways in them),
    then the divergence theorem sums the triangles' cones from the points' centre."""
    owner: dict[tuple[int, int], tuple[int, bool]] = {}
    links: list[list[tuple[int, bool]]] = [[] for _ in faces]
    for k, tri in enumerate(faces):
        directed = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        _, inverse, count = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True, return_counts=True)
        for a, b in directed[count[inverse.ravel()] == 1]:  # the face's edges on its curves
            e, forward = (min(a, b), max(a, b)), bool(a < b)
            if e in owner:  # the same direction in both faces: one of them turns the wrong way
                other, theirs = owner[e]
                links[k].append((other, theirs == forward))
                links[other].append((k, theirs == forward))
            else:
                owner[e] = (k, forward)
    sign = np.zeros(len(faces))
    for start in range(len(faces)):
        if sign[start]:
            continue
        sign[start], todo = 1.0, [start]
        while todo:
            k = todo.pop()
            for other, flip in links[k]:
                if not sign[other]:
                    sign[other] = -sign[k] if flip else sign[k]
                    todo.append(other)
    c = points.mean(axis=0)
    six = sum(s * float(np.einsum("ij,ij->", points[t[:, 0]] - c, np.cross(points[t[:, 1]] - c, points[t[:, 2]] - c)))
              for s, t in zip(sign, faces))
    return abs(six) / 6


def signed_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volume of each tet (E,) [mm^3]: positive for the orientation gmsh and DOLFINx use."""
    p = points[tets]
    return np.einsum("ij,ij->i", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0])) / 6


def phase_mismatch(textile: Textile, points: np.ndarray, tets: np.ndarray, phase: np.ndarray) -> dict:
    """Elements whose centroid the model does not put in their own phase: a yarn element whose
    centroid is outside its yarn, a matrix element whose centroid is inside a yarn, any centroid
    inside two yarns. Returns counts and the volume they hold [mm^3]."""
    c = points[tets].mean(axis=1)
    inside = textile.inside(c)
    own = np.where(phase > 0, inside[np.arange(len(c)), np.maximum(phase - 1, 0)], ~inside.any(axis=1))
    two = inside.sum(axis=1) > 1
    bad = ~own | two
    vol = np.abs(signed_volumes(points, tets))
    return {"elements": int(bad.sum()), "fraction": float(bad.mean()) if len(bad) else 0.0,
            "volume": float(vol[bad].sum()), "in_two_yarns": int(two.sum())}


def fibre_angles(textile: Textile, points: np.ndarray, tets: np.ndarray, phase: np.ndarray,
                 fibre: np.ndarray) -> np.ndarray:
    """Per yarn element, the angle [deg] between its fibre direction and the tangent of its yarn's
    centreline at the point of the centreline nearest its centroid (sampled ten times finer than
    the fibre directions were)."""
    c = points[tets].mean(axis=1)
    angles = np.zeros(0)
    for i, y in enumerate(textile.yarns):
        k = np.flatnonzero(phase == i + 1)
        if not len(k):
            continue
        s = y.stations(textile.resolution.spacing / 40)
        pos, tan = y.centreline(s)
        reps = [np.zeros(3)] + [a * r for r in textile.cell.repeats for a in (-1, 1)] + \
               [a * textile.cell.repeats[0] + b * textile.cell.repeats[1] for a in (-1, 1) for b in (-1, 1)]
        shifts = [np.zeros(3)]
        if y.periodic:
            shifts = [r + k_ * y.period for r in reps for k_ in (-1, 0, 1)]
        else:
            shifts = reps
        cloud = np.concatenate([pos + t for t in shifts])
        tangents = np.tile(tan, (len(shifts), 1))
        _, j = cKDTree(cloud).query(c[k])
        cos = np.abs(np.einsum("ij,ij->i", tangents[j], fibre[k]))
        angles = np.concatenate([angles, np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))])
    return angles
