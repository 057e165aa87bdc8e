"""Where the sides of a tet mesh's box cut the yarns (meshes/tetra_solids.py builds the solids).

The box cuts each yarn's skin, a chain of ruled faces between section stations. A station just
beside a side leaves a thin strip of ruled face between it and the cut (a sliver tet on the plain
weave, 0.07 mm from y1), so it is left out where the skin without it stays within a fraction of
the gap (`beside`). Where a yarn turns right at a side, as the binders of TexGen's orthogonal weave
do (their legs run along x = 0, the cell's side, centred on it to 0.004 mm), no station can be
left out, and OCC's cut of the skin by the box gives nothing, whatever its fuzzy tolerance. A
periodic cell's box may start anywhere, though: `shift` moves it along the cell's sides to where
every yarn runs straight through them.
"""

from __future__ import annotations

import numpy as np

from textile_fenicsx.textile import Textile

# A station closer than this fraction of the spacing to a side of the box it crosses is left out,
# where the skin without it strays by at most STRAY x the gap the mesh is made for.
BESIDE = 0.4
STRAY = 0.25


def near_sides(centre: np.ndarray, period: np.ndarray, lo: np.ndarray, L: np.ndarray, spacing: float,
               axes: tuple[int, ...] = (0, 1)) -> np.ndarray:
    """Which stations (centres (M, 3) [mm]) of a periodic yarn lie nearer than BESIDE x spacing to a
    side of the box [lo, lo + L] (or its periodic images) that the yarn runs through, along `axes`;
    never the chain's ends."""
    near = np.zeros(len(centre), bool)
    for ax in axes:
        if abs(period[ax]) > 1e-9:
            r = (centre[:, ax] - lo[ax]) / L[ax]
            near |= np.abs(r - np.round(r)) * L[ax] < BESIDE * spacing
    near[[0, -1]] = False
    return near


def strays(sec: np.ndarray, left_out: np.ndarray) -> np.ndarray:
    """How far [mm] the skin ruled between the stations kept passes from the sections (M, K, 3) of
    each station left out (the largest over its points, each against the point of the same index
    interpolated by arc length along the centres); the chain's ends are kept."""
    centre = sec.mean(axis=1)
    arc = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(centre, axis=0), axis=1))))
    kept, out = np.flatnonzero(~left_out), np.flatnonzero(left_out)
    after = np.searchsorted(kept, out)
    a, b = kept[after - 1], kept[after]
    w = ((arc[out] - arc[a]) / (arc[b] - arc[a]))[:, None, None]
    return np.linalg.norm(sec[out] - ((1 - w) * sec[a] + w * sec[b]), axis=-1).max(axis=1)


def beside(sec: np.ndarray, period: np.ndarray, lo: np.ndarray, L: np.ndarray, spacing: float,
           tolerance: float) -> np.ndarray:
    """Which stations of a periodic yarn's chain (M, K, 3) to leave out: those near a side
    (`near_sides`), but only while the skin ruled between the stations kept passes within
    `tolerance` [mm] of every point of their sections (the station it would miss most is put back
    first). On TexGen's orthogonal weave the binders turn 0.03-0.08 mm from a side: left out, those
    stations moved the skin by 0.05 mm, across the 0.008 mm gap and into the weft beside it."""
    left_out = near_sides(sec.mean(axis=1), period, lo, L, spacing)
    while left_out.any():
        stray = strays(sec, left_out)
        worst = int(np.argmax(stray))
        if stray[worst] <= tolerance:
            break
        left_out[np.flatnonzero(left_out)[worst]] = False
    return left_out


def shift(textile: Textile, sections: list[np.ndarray], lo: np.ndarray, hi: np.ndarray, spacing: float,
          gap: float) -> np.ndarray:
    """The shift (dx, dy, 0) [mm] of the box [lo, hi] along the cell's sides, the least found in
    steps of spacing / 4 up to half the cell, after which (1) every station near a side can be left
    out with the skin straying by at most STRAY x gap, and (2) a side that cuts a yarn lengthwise
    (one running along it) passes at least BESIDE x spacing inside its edges (a cut grazing a weft's
    edge 0.0125 mm inside it lost that face on one side of the box only, and the sides did not
    pair). The sides then cut the yarns where they run straight and squarely. sections: each yarn's
    section polygons (M, K, 3) over one period (tetra_solids.yarn_sections). Zero where the box is
    already so; where no shift is, the one that strays least."""
    L = hi - lo
    band = BESIDE * spacing
    out = np.zeros(3)
    for ax in (0, 1):
        through, along = [], []
        for y, one in zip(textile.yarns, sections):
            if y.periodic and abs(y.period[ax]) > 1e-9:
                through.append((y.period, np.concatenate([one[:-1] + k * y.period for k in (-1, 0, 1)]
                                                         + [one[-1:] + y.period])))
            else:
                along.append(np.stack([one[..., ax].min(axis=1), one[..., ax].max(axis=1)], axis=1))
        edges = np.concatenate(along) if along else np.zeros((0, 2))
        step = spacing / 4
        best, least = 0.0, np.inf
        for k in [0] + [s * j for j in range(1, int(L[ax] / 2 / step) + 1) for s in (1, -1)]:
            d = np.zeros(3)
            d[ax] = k * step
            worst = 0.0
            for period, sec in through:
                near = near_sides(sec.mean(axis=1), period, lo + d, L, spacing, (ax,))
                if near.any():
                    worst = max(worst, float(strays(sec, near).max()))
            side = lo[ax] + d[ax] + np.ceil((edges[:, 0] - lo[ax] - d[ax]) / L[ax]) * L[ax]  # first side past
            cut = side < edges[:, 1]                                                         # each section's edge
            grazing = bool(np.any(np.minimum(side - edges[:, 0], edges[:, 1] - side)[cut] < band))
            if worst < least and not grazing:
                best, least = d[ax], worst
            if worst <= STRAY * gap and not grazing:
                break
        out[ax] = best
    return out
