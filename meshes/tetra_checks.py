"""Checks of a tet mesh and of the model it is made from (meshes/tetra.py): pure numpy.

- `yarn_gaps`: the least vertical gap between any two yarns over a grid of the cell (negative: an
  overlap), with the pair and the place, measured by the model's vertical rays;
- `signed_volumes`, `phase_mismatch`, `fibre_angles`: inverted tets, elements whose centroid is
  not in their own yarn, fibre directions against the path tangent.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from textile_fenicsx.textile import Textile


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
