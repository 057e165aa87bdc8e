"""Caps in the projected mesh: triangles whose three corners lie nearly on one line.

Where two yarn edges leave each other at a tiny angle (TexGen's refined orthogonal weaves: an
outer weft widened by a ramped blend parts from the middle weft's edge), the wedge between them has
a corner of almost no angle, and gmsh's triangle at its tip has its third corner on its longest
edge: angles of 0.17-0.18 (twice) and 179.6-179.7 degrees on the refined t1.8 weave, four of
them, every other triangle above 11 degrees. A plate element that flat is all but singular: the contact solve's
steps at those four corners wandered by 1e-4 mm for 300 steps without settling.

On that weave the edge from which the cap hangs bends by 0.37 degrees the other way, so that the
cap is turned over: its middle corner lies inside the neighbour across its longest edge, and the
two overlap. Either way the cap and that neighbour are replaced by the two triangles from the
cap's middle corner to the neighbour's far corner, oriented as the neighbour was. They tile the
neighbour less the overlap (a cap turned over) or the quadrilateral (a cap the right way up, whose
area, under 1e-5 mm^2, then goes to the neighbour's region), and meet the regions on both sides of
the cap's short edges. A mesh without caps is returned as it is.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CAP_ANGLE", "flip_caps", "triangle_angles"]

# deg: a triangle with an angle below this and one above 180 - 2 x this is a cap
CAP_ANGLE = 1.0


def triangle_angles(p: np.ndarray) -> np.ndarray:
    """Interior angles in degrees of triangles p (T, 3, 2)."""
    out = np.empty(p.shape[:2])
    for k in range(3):
        a, b, c = p[:, k], p[:, (k + 1) % 3], p[:, (k + 2) % 3]
        u, v = b - a, c - a
        cos = np.einsum("ij,ij->i", u, v) / (np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1))
        out[:, k] = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    return out


def _area(p: np.ndarray) -> np.ndarray:
    """Signed areas of triangles p (T, 3, 2) (positive: counter-clockwise)."""
    u, v = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return 0.5 * (u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])


def flip_caps(x: np.ndarray, cells: np.ndarray, tags: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """The mesh (nodes x (N, 2), cells (M, 3), region tags (M,)) with each cap and its neighbour
    across its longest edge made two triangles from the cap's middle corner, where those are valid
    and better shaped (module docstring): (cells, tags, how many caps were replaced)."""
    angles = triangle_angles(x[cells])
    caps = np.flatnonzero((angles.min(axis=1) < CAP_ANGLE) & (angles.max(axis=1) > 180.0 - 2 * CAP_ANGLE))
    if len(caps) == 0:
        return cells, tags, 0
    cells, tags, flipped = cells.copy(), tags.copy(), 0
    for t in caps:
        k = int(np.argmax(triangle_angles(x[cells[t]][None])[0]))
        m, p, q = cells[t, k], cells[t, (k + 1) % 3], cells[t, (k + 2) % 3]  # m: the corner on edge p-q
        across = np.flatnonzero((cells == p).any(axis=1) & (cells == q).any(axis=1))
        across = across[across != t]
        if len(across) != 1:  # the edge is on the cell's side: nothing to flip with
            continue
        n = int(across[0])
        c = int(cells[n][(cells[n] != p) & (cells[n] != q)][0])
        sign = np.sign(_area(x[cells[[n]]])[0])  # the neighbour's orientation: the cap's may be turned over
        new = np.array([[m, p, c], [m, c, q]])
        if np.any(np.sign(_area(x[new])) != sign):  # m is past c, or c past the line through m
            continue
        old = triangle_angles(x[cells[[t, n]]]).min()
        if triangle_angles(x[new]).min() <= old:
            continue
        cells[t], cells[n] = new
        tags[t] = tags[n]
        flipped += 1
    return cells, tags, flipped
