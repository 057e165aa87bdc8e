"""Where the sides of a tet mesh's box cut the yarns (options.py and surface_mesh.py build the box,
solids.py the yarns).

The box cuts each yarn's skin, a chain of ruled faces between section stations:
- A station of a yarn that crosses a side, nearer than BESIDE x spacing to it, is left out of the
  skin (`left_out`). Otherwise the cut leaves a thin strip of ruled face beside it: a sliver tet on
  the plain weave, 0.07 mm from y1.
- A station where the yarn runs along the side (its tangent within 30 degrees of the side's plane:
  a binder's leg) is kept where leaving out every station near a side would move a skin by more
  than LEGS x the gap (`legs_on_sides`). TexGen's orthogonal binders have vertical legs centred on
  their weft gaps, x = 0 among them, to 0.004 mm. Left out, a leg's stations took the turn out of
  its skin, which then cut 0.05 mm into the weft beside it, across a gap of 0.008 mm. Our own
  orthogonal weave, and the angle interlock and layer-to-layer weaves, meshed with them left out
  (their skins moved by 6.2-6.8 x the gap); ours lost a binder in OCC's cut with them kept.
- OCC's cut of such a binder's skin by the box at x = 0 returned nothing, for any station rule
  tried. The same cut at x = 2.8 or 5.6 mm, through legs of the same shape, keeps the binder.
  A periodic cell's box may start anywhere, so where a yarn is lost in the cut the box moves
  (`moves`): into a gap between the yarns that run along that axis's sides, nearest the origin
  first. A side there cuts no yarn lengthwise other than the legs in the gap, and a leg's straight
  stretch is avoided too: at a gap's middle the side ran along the edges of the leg centred there
  (its sections' tips, within 1.4e-6 mm), and gmsh left flat tets in the sliver on ortho_w3f4.
  So the side lies midway between the leg's straight stretch and the gap's end (the middles of
  the gap's stretches clear of legs, those at least half as wide as the widest); at the gap's
  middle where legs fill it.
"""

from __future__ import annotations

import numpy as np

from textile_fenicsx.model.textile import Textile

# A station closer than this fraction of the spacing to a side of the box it crosses is left out.
BESIDE = 0.4
# ... where the yarn crosses it: |tangent . side's normal| above this (cos 60 degrees)
CROSSING = 0.5
# ... where it runs along it, as a binder's straight leg: |tangent . side's normal| at most this
# (within 3 degrees of the side's plane)
ALONG = 0.05
# a move by less than this fraction of the cell is the box where it is
STILL = 0.01
# legs keep their stations where leaving out the stations near the sides would move a skin by more
# than this many gaps: 13.5-14.6 on TexGen's orthogonal weaves (which then failed), 6.2-6.8 on our
# orthogonal weave, the angle interlock and layer-to-layer weaves (which meshed), 0.12 at most on
# the 2D weaves
LEGS = 10.0


def left_out(centre: np.ndarray, period: np.ndarray, lo: np.ndarray, length: np.ndarray,
             spacing: float, legs: bool = False) -> np.ndarray:
    """Which stations (centres (M, 3) [mm], a chain of a periodic yarn) to leave out of its skin:
    nearer than BESIDE x spacing to a side of the box [lo, lo + length] (or its periodic images)
    that the yarn runs through; with `legs`, only where the yarn crosses it (a leg running down
    the side keeps its stations); never the chain's ends."""
    tangent = np.gradient(centre, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1), 1e-12)[:, None]
    out = np.zeros(len(centre), bool)
    for ax in (0, 1):
        if abs(period[ax]) > 1e-9:
            r = (centre[:, ax] - lo[ax]) / length[ax]
            near = np.abs(r - np.round(r)) * length[ax] < BESIDE * spacing
            out |= near & (np.abs(tangent[:, ax]) > CROSSING) if legs else near
    out[[0, -1]] = False
    return out


def strays(sec: np.ndarray, left: np.ndarray) -> np.ndarray:
    """How far [mm] the skin ruled between the stations kept passes from the sections (M, K, 3) of
    each station left out: the largest distance of a section point from the point of the same index
    interpolated by arc length between the kept stations on either side."""
    centre = sec.mean(axis=1)
    arc = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(centre, axis=0), axis=1))))
    kept, out = np.flatnonzero(~left), np.flatnonzero(left)
    after = np.searchsorted(kept, out)
    a, b = kept[after - 1], kept[after]
    w = ((arc[out] - arc[a]) / (arc[b] - arc[a]))[:, None, None]
    return np.linalg.norm(sec[out] - ((1 - w) * sec[a] + w * sec[b]), axis=-1).max(axis=1)


def legs_on_sides(textile: Textile, sections: list[np.ndarray], lo: np.ndarray, hi: np.ndarray, spacing: float,
                  gap: float) -> bool:
    """Whether the skins must keep the legs' stations on the box's sides: leaving out every station
    near a side moves some skin by more than LEGS x the gap (module docstring). sections: each
    yarn's section polygons (M, K, 3) over one period (solids.yarn_sections)."""
    worst = 0.0
    for y, one in zip(textile.yarns, sections):
        if y.periodic:
            chain = np.concatenate([one[:-1] + k * y.period for k in (-1, 0, 1)] + [one[-1:] + y.period])
            left = left_out(chain.mean(axis=1), y.period, lo, hi - lo, spacing)
            if left.any():
                worst = max(worst, float(strays(chain, left).max()))
    return worst > LEGS * gap


def _uncovered(spans: list[tuple[float, float]], start: float, end: float) -> list[tuple[float, float]]:
    """The stretches of [start, end] that no interval (a, b) of `spans` covers."""
    out, at = [], start
    for a, b in sorted(spans):
        if a >= end:
            break
        if a > at:
            out.append((at, a))
        at = max(at, b)
    if end > at:
        out.append((at, end))
    return out


def _gaps(extents: np.ndarray, lo: float, length: float) -> list[tuple[float, float]]:
    """The gaps (start, end) [mm, from lo; start in [0, length)] between intervals (N, 2) [mm] on a
    circle of `length` starting at lo; none where the intervals leave no gap."""
    if len(extents) == 0:
        return []
    a = (extents[:, 0] - lo) % length
    spans = sorted(zip(a, a + extents[:, 1] - extents[:, 0]))
    gaps = _uncovered(spans, spans[0][1], spans[0][0] + length)
    return [(s % length, s % length + e - s) for s, e in gaps]


def _clear_middles(start: float, end: float, legs: np.ndarray, lo: float, length: float) -> list[float]:
    """Where in the gap [start, end] (from lo) a side may lie: the middles of its stretches clear of
    the legs' extents (N, 2) [mm] at least half as wide as the widest; the gap's middle where the
    legs leave none clear."""
    a = (legs[:, 0] - lo) % length
    stretches = _uncovered([(s + k * length, s + k * length + w) for s, w in zip(a, legs[:, 1] - legs[:, 0])
                            for k in (-1, 0, 1)], start, end)
    if not stretches:
        return [(start + end) / 2]
    widest = max(e - s for s, e in stretches)
    return [(s + e) / 2 for s, e in stretches if e - s >= widest / 2]


def _legs(textile: Textile, sections: list[np.ndarray], ax: int) -> np.ndarray:
    """The extents (N, 2) along axis ax [mm] of the sections where a yarn that crosses that axis's
    sides runs along them (its tangent within 3 degrees of their plane: a binder's straight leg)."""
    out = [np.zeros((0, 2))]
    for y, one in zip(textile.yarns, sections):
        if y.periodic and abs(y.period[ax]) > 1e-9:
            tangent = np.gradient(one.mean(axis=1), axis=0)
            leg = np.abs(tangent[:, ax]) <= ALONG * np.maximum(np.linalg.norm(tangent, axis=1), 1e-12)
            out.append(np.stack([one[leg][..., ax].min(axis=1), one[leg][..., ax].max(axis=1)], axis=1))
    return np.concatenate(out)


def moves(textile: Textile, sections: list[np.ndarray], lo: np.ndarray, hi: np.ndarray) -> list[np.ndarray]:
    """Shifts (dx, dy, 0) [mm] of the box [lo, hi] to try, in order, where OCC's cut loses a yarn:
    along x, then along y, into the gaps between the yarns that do not cross that axis's sides,
    midway between the legs there and their sides (nearest the box's own place first; none within
    STILL x the cell of it). sections: each yarn's section polygons (M, K, 3) over one period
    (solids.yarn_sections)."""
    out = []
    for ax in (0, 1):
        extents = _along(textile, sections, ax)
        legs = _legs(textile, sections, ax)
        length = float(hi[ax] - lo[ax])
        places = np.array([m for s, e in _gaps(extents, float(lo[ax]), length)
                           for m in _clear_middles(s, e, legs, float(lo[ax]), length)]) % length
        places = np.where(places > length / 2, places - length, places)
        for d in sorted(places, key=lambda d: (round(abs(d), 9), d)):
            if abs(d) > STILL * length:
                move = np.zeros(3)
                move[ax] = d
                out.append(move)
    return out


def _along(textile: Textile, sections: list[np.ndarray], ax: int) -> np.ndarray:
    """The extents (N, 2) along axis ax [mm] of each section of the yarns that do not cross that
    axis's sides (they run along them)."""
    along = [np.stack([one[..., ax].min(axis=1), one[..., ax].max(axis=1)], axis=1)
             for y, one in zip(textile.yarns, sections) if not (y.periodic and abs(y.period[ax]) > 1e-9)]
    return np.concatenate(along) if along else np.zeros((0, 2))


def clear_of_edges(textile: Textile, sections: list[np.ndarray], lo: np.ndarray, hi: np.ndarray,
                   ax: int) -> list[float]:
    """Shifts along axis ax [mm] that put the box's sides across that axis far from every edge of
    the yarns running along them: the middles of the stretches between two edges (their sections'
    extents, over the cell's period), through a yarn or a gap, the longest first (nearest the
    cell's own place on ties), so that every skin meets the side steeply. Where a side cut a yarn
    0.096 mm inside its edge, along its length (TexGen's refined t1.92, y = 0), its skin met the
    side at a grazing angle and gmsh's volume mesh failed (overlapping facets); through the
    yarns' middles it meshed."""
    length = float(hi[ax] - lo[ax])
    edges = np.sort((_along(textile, sections, ax).ravel() - float(lo[ax])) % length)
    if len(edges) == 0:
        return []
    stretch = np.diff(np.append(edges, edges[0] + length))
    middles = (edges + stretch / 2) % length
    middles = np.where(middles > length / 2, middles - length, middles)
    order = sorted(range(len(edges)), key=lambda k: (-round(float(stretch[k]), 9), round(abs(float(middles[k])), 9)))
    return [float(middles[k]) for k in order]
