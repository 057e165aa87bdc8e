"""Footprints: each yarn's outline seen along z (DESIGN.md section 4, step 1).

The outline of a yarn comes from the lateral extremes of its sections at stations along it, one
(right, left) pair of side chains per lateral copy of the yarn that reaches the cell, chained over
neighbouring periods so that it covers the cell along the yarn; the projected mesh clips them to
the cell. `footprint_area` measures the part inside the cell, independently of any mesh.
"""

import numpy as np

from textile_fenicsx.queries import translations
from textile_fenicsx.textile import Textile

__all__ = ["footprint_area", "footprint_outlines"]


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


