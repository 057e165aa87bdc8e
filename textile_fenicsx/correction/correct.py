"""Correction of the textile from the yarns' displacements (DESIGN.md section 7).

For each yarn, at stations along its centreline: the centreline point moves by w at its in-plane
position, and every point of the section moves by w at its own in-plane position (on steep stretches
only its across-fibre offset counts), so sections bend and twist with the mid-surface. The section
is then laid in the plane normal to the new path: its across-fibre coordinate is kept, its height
coordinate gets the shift times the vertical part of the new up vector, and where the path
steepens the section thins by new_up_z / old_up_z, which keeps the vertical thickness the plates
kept. Where the path flattens (a binder's steep stretch smoothed)
the section keeps its own thickness: moving the points vertically and projecting them on the new
plane, the literal reading of DESIGN.md, collapses sections there (they lay along the old path).
Bent with the plate across its width a section's centroid leaves the path: the path is then moved
onto the centroids, and the sections cut anew from the same surface normal to it (_centred), so
that a yarn holds its sections' area per length of its path. The corrected yarn is a periodic
cubic through the moved stations (stations.py: closer where the path turns, at most as many as a
model may have master nodes) with one polygon section per station, so every query, metric and
export of the model works on it.
"""


import logging
from dataclasses import dataclass, replace

import numpy as np

from textile_fenicsx.common.errors import GeometryError, TextileError, check_positive
from textile_fenicsx.common.limits import MAX_NODES, MAX_NODES_PER_YARN, MAX_SURFACE_POINTS
from textile_fenicsx.correction.stations import budgets, stations
from textile_fenicsx.correction.verify import self_intersecting
from textile_fenicsx.model.sections import Polygon, polygon_centroids
from textile_fenicsx.model.textile import Cell, Resolution, Textile
from textile_fenicsx.model.yarn import ConstantSection, NodeSections, PositionSections, Yarn
from textile_fenicsx.plate.point_values import evaluate, nearest_images

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CorrectionOptions:
    """How the corrected yarns are sampled. spacing: distance between stations along each yarn
    [mm] (default: half the mesh seed, at most 0.25 mm); section_points: points per section
    polygon [-] (64: the polygon encloses 0.16 % less than an ellipse)."""

    spacing: float | None = None
    section_points: int = 64

    def __post_init__(self):
        if self.spacing is not None:
            check_positive("correction spacing", self.spacing)
        if not (isinstance(self.section_points, int) and 8 <= self.section_points <= 4096):
            raise TextileError(f"section_points must be a whole number from 8 to 4096, got {self.section_points!r}")

    def station_spacing(self, seed: float) -> float:
        """The stations' spacing for a mesh of this seed [mm]."""
        return self.spacing if self.spacing is not None else min(seed / 2, 0.25)


class _Whole:
    """The displacement of a yarn that is one plate: w (a Function on its mid-surface)."""

    def __init__(self, w, cell: Cell):
        self.w, self.cell = w, cell

    def centre(self, s: np.ndarray, xy: np.ndarray) -> np.ndarray:
        return evaluate(self.w, self.cell.wrap(xy))

    def points(self, s: np.ndarray, xy: np.ndarray, w_centre: np.ndarray) -> np.ndarray:
        # points just outside the meshed footprint (its edge is a spline through the outline) take
        # w from the nearest element
        return evaluate(self.w, self.cell.wrap(xy.reshape(-1, 2)), extrapolate=True).reshape(xy.shape[:2])


class Flat:
    """A yarn plate's flattening (compaction.py): a point of a section moves, besides w, toward
    the section's mid-height over it (correct._mid_heights) by its height above it times dt / t at
    its own in-plane point, so the section thins about its middle as the plate's thickness t does
    (DESIGN.md 7). The section's own middle, not the plate's mid-height z0 there: z0 extrapolated to
    the section points just outside the footprint (rays graze the yarn's edge) moved a plain
    weave's weft edges 0.02 mm into the warps; nor the section's centre line: TexGen's refined
    sections are not symmetric about it, and thinned about it their tops moved less than the
    plates' (a refined plain weave overlapped 7.7e-4 mm^3). dt / t is read within the range of its
    nodal values, `bounds`: its interpolant overshoots near the edges."""

    def __init__(self, ratio, bounds: tuple[float, float], cell: Cell):
        self.ratio, self.bounds, self.cell = ratio, bounds, cell  # ratio: dt / t (a Function)

    def shift(self, xy: np.ndarray, height: np.ndarray) -> np.ndarray:
        """The flattening's move of section points at in-plane xy, `height` above their centre [mm]."""
        ratio = evaluate(self.ratio, self.cell.wrap(xy.reshape(-1, 2)), extrapolate=True).reshape(height.shape)
        return height * np.clip(ratio, *self.bounds)


# A leg's change of length goes where it is vertical: its height is weighted by the vertical part
# of its tangent to this power (1 in the straight middle, 0.43 where it leans 25 degrees, 0.13 at
# the slope of 3 where it meets its crowns). Shortened evenly in height, the rounded ends were
# squeezed too: TexGen's orthogonal binders at seed 0.5 then turned at 15/mm (0.08 mm half-height)
VERTICAL = 8


def _climb(yarn: Yarn, s: np.ndarray, per_segment: int = 64) -> np.ndarray:
    """The height the centreline climbs or falls from its start to parameters s [mm]: |dz|
    summed, weighted by |tangent_z| ** VERTICAL; s may run past the ends of a periodic yarn (a
    whole period adds the period's sum)."""
    dense = np.linspace(0, yarn.n_segments, yarn.n_segments * per_segment + 1)
    pos, tan = yarn.centreline(dense)
    steep = (0.5 * (np.abs(tan[1:, 2]) + np.abs(tan[:-1, 2]))) ** VERTICAL
    table = np.concatenate(([0.0], np.cumsum(np.abs(np.diff(pos[:, 2])) * steep)))
    if not yarn.periodic:
        return np.interp(s, dense, table)
    n = yarn.n_segments
    wraps = np.floor(s / n)
    return np.interp(s - wraps * n, dense, table) + wraps * table[-1]


class _Crowns:
    """The displacement of a yarn cut into crowns (legs.py): each station on a crown takes that
    crown's plate; a leg's stations take the displacements of its two crown ends, interpolated
    along the leg in the height it descends or climbs (the leg's sections move as a whole)."""

    def __init__(self, yarn: Yarn, pieces: list, cell: Cell):
        self.yarn, self.pieces, self.cell = yarn, pieces, cell  # pieces: [(crown, w, plate yarn)]

    def _owner(self, s: np.ndarray) -> np.ndarray:
        n = self.yarn.n_segments
        owner = np.full(len(s), -1)
        for k, (crown, _, _) in enumerate(self.pieces):
            for shift in (0.0, n, -n):
                owner[(s + shift >= crown.s0 - 1e-12) & (s + shift <= crown.s1 + 1e-12)] = k
        return owner

    def _on(self, w, xy: np.ndarray) -> np.ndarray:
        """A crown's w at in-plane points xy (collective); a point outside the crown's plate is
        read at its image nearest the plate: a crown that ends on a cell side has no mesh across
        it, and a station on that side, wrapped to the other, took the value at its other end."""
        xy = self.cell.wrap(xy)
        if not self.cell.periodic:
            return evaluate(w, xy, extrapolate=True)
        out = evaluate(w, xy)
        off = np.isnan(out)  # the same on every rank
        if np.any(off):
            moves = self.cell.neighbours() if self.cell.shift else (self.cell.lx, self.cell.ly)
            out[off] = evaluate(w, nearest_images(w.function_space.mesh, xy[off], moves), extrapolate=True)
        return out

    def centre(self, s: np.ndarray, xy: np.ndarray) -> np.ndarray:
        owner, out = self._owner(s), np.full(len(s), np.nan)
        ends = []  # (parameter, w) at every crown's start and end
        for k, (crown, w, plate) in enumerate(self.pieces):
            on = owner == k
            out[on] = self._on(w, xy[on]) if np.any(on) else []
            tips = self._on(w, plate.nodes[[0, -1], :2])
            ends += [(crown.s0, tips[0]), (crown.s1, tips[1])]
        legs = owner < 0
        if np.any(legs):
            n = self.yarn.n_segments
            ps = np.array([e[0] for e in ends])
            ws = np.array([e[1] for e in ends])
            order = np.argsort(ps)
            ps, ws = ps[order], ws[order]
            if self.yarn.periodic:  # the legs between the last end and the first start wrap
                ps, ws = np.r_[ps[-1] - n, ps, ps[0] + n], np.r_[ws[-1], ws, ws[0]]
            t = s[legs] - np.floor((s[legs] - ps[0]) / n) * n if self.yarn.periodic else s[legs]
            out[legs] = self._along_legs(t, ps, ws)
        return out

    def _along_legs(self, t: np.ndarray, ps: np.ndarray, ws: np.ndarray) -> np.ndarray:
        """w at leg parameters t between crown ends at parameters ps (sorted) with w = ws: each
        leg stretched or shortened in its vertical middle (_climb), w interpolated in the height
        the path has climbed (or fallen) from the leg's start, not in the path parameter. A leg's
        ends are rounded (its slope falls to the crowns' 3): in the parameter they took as much
        of its shortening as its vertical middle, more than they fall there, and the path turned
        back (TexGen's orthogonal weave at seed 0.5: a leg 1.4 mm high shortened by 0.35 mm rose
        0.01 mm after its lower corner, whose sections then folded over each other)."""
        k = np.clip(np.searchsorted(ps, t, side="right") - 1, 0, len(ps) - 2)
        climb = _climb(self.yarn, np.concatenate((ps, t)))
        c0, c1, c = climb[k], climb[k + 1], climb[len(ps):]
        frac = np.where(c1 > c0, (c - c0) / np.where(c1 > c0, c1 - c0, 1.0),
                        (t - ps[k]) / np.maximum(ps[k + 1] - ps[k], 1e-300))
        return ws[k] + (ws[k + 1] - ws[k]) * np.clip(frac, 0.0, 1.0)

    def points(self, s: np.ndarray, xy: np.ndarray, w_centre: np.ndarray) -> np.ndarray:
        owner, out = self._owner(s), np.repeat(w_centre[:, None], xy.shape[1], axis=1)
        for k, (_, w, _) in enumerate(self.pieces):
            on = owner == k
            if np.any(on):
                out[on] = self._on(w, xy[on].reshape(-1, 2)).reshape(-1, xy.shape[1])
            else:
                evaluate(w, np.zeros((0, 2)), extrapolate=True)  # collective
        return out


def corrected_yarn(textile: Textile, i: int, w, spacing: float, n_points: int = 32,
                   section_tol: float | None = None, most: int | None = None, flat: Flat | None = None) -> Yarn:
    """Yarn i moved by its displacement: w, a Function on its mid-surface (or, for a yarn cut
    into crowns, a _Crowns of their Functions), at stations (stations.py; at most `most`). Its
    sections are kept where the blend of their neighbours misses them by more than section_tol
    [mm] (default SECTION_TOL of the height; 0 keeps every station's). flat: the yarn's flattening
    (a yarn that is one plate), whose sections then hold the area it leaves them."""
    yarn = textile.yarns[i]
    w = w if isinstance(w, _Crowns) else _Whole(w, textile.cell)
    s = stations(yarn, spacing, most)
    pos, _, up, side = yarn.frames(s)
    sec = yarn.section_points(s, n_points)
    # section coordinates in the unrotated frame (side0 horizontal): (u0 across, v0 up)
    rel = sec[..., :1] * side[:, None, :] + sec[..., 1:] * up[:, None, :]
    _, _, up0, side0 = (replace(yarn, angles=None) if yarn.angles is not None else yarn).frames(s)
    u0 = np.einsum("mkj,mj->mk", rel, side0)
    v0 = np.einsum("mkj,mj->mk", rel, up0)
    w_centre = w.centre(s, pos[:, :2])
    if np.any(np.isnan(w_centre)):
        k = int(np.flatnonzero(np.isnan(w_centre))[0])
        raise GeometryError(f"{yarn.name}: its centreline at ({pos[k, 0]:.3f}, {pos[k, 1]:.3f}) mm lies outside "
                            "its meshed footprint; cannot correct it")
    # w at each section point's own in-plane position: the yarn's surface over a point moves with
    # the plate's mid-surface there, which keeps the gaps the plates closed. On steep stretches the
    # section's extent along the path is the path's slope, not the mid-surface's: that part of the
    # offset fades with cos^2 of the slope (else sections shear where w varies across a column)
    fade = up0[:, 2] ** 2
    pts_xy = (pos[:, None, :2] + u0[..., None] * side0[:, None, :2]
              + (v0 * fade[:, None])[..., None] * up0[:, None, :2])
    w_pts = w.points(s, pts_xy, w_centre)
    if flat is not None:  # each point also moves toward the section's mid-height over it as the yarn thins
        flat_pts = flat.shift(pts_xy, (v0 - _mid_heights(u0, v0)) * up0[:, None, 2])
        w_pts = w_pts + flat_pts
    new_pos = pos + np.outer(w_centre, [0.0, 0.0, 1.0])
    if yarn.periodic:  # the last station repeats the first, shifted by the period
        new_pos[-1] = new_pos[0] + yarn.period
        w_pts[-1] = w_pts[0]
        w_centre[-1] = w_centre[0]
    # lay the section in the new frame (see the module docstring)
    ups = up0 if yarn.ups is not None else None
    probe = Yarn(new_pos, ConstantSection(yarn.section.sections()[0]), "cubic", yarn.periodic, yarn.repeats,
                 ups=ups, name=yarn.name, fibres=yarn.fibres)
    _, _, new_up, _ = probe.frames(np.arange(len(s), dtype=float))
    v_new = v0 + (w_pts - w_centre[:, None]) * new_up[:, None, 2]
    # the section keeps its area (its fibres): the plates keep the vertical thickness, which
    # changes the area normal to the path where the slope changes (by cos(new) / cos(old)), and
    # the vertical shift varies over a tilted section. Where the area would grow the section
    # narrows; where it would shrink it thickens (widening would raise the thin flanks over the
    # neighbours, thickening spends the margin the exact contact keeps at the nodes)
    kept = _areas(u0, v0) if flat is None else \
        _areas(u0, v0 + flat_pts * up0[:, None, 2])  # the flattened section's
    ratio = (kept / _areas(u0, v_new))[:, None]
    u_new, v_new = u0 * np.minimum(1.0, ratio), v_new * np.maximum(1.0, ratio)
    new_pos, polys = _centred(probe, new_pos, np.stack((u_new, v_new), axis=-1), yarn.periodic)
    tol = SECTION_TOL * _heights(polys).min() if section_tol is None else section_tol
    return Yarn(new_pos, sparse_sections(new_pos, polys, yarn.periodic, tol),
                "cubic", yarn.periodic, yarn.repeats, ups=ups, name=yarn.name, fibres=yarn.fibres)


def _mid_heights(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Per polygon (u[m], v[m]), at each of its points the mid-height of the polygon over that
    point's u: the mean of its two chains from its leftmost to its rightmost point there (a
    section's, seen across the yarn). 0 for sections symmetric about their centre line."""
    mid = np.empty_like(v)
    n = u.shape[1]
    for m in range(len(u)):
        a, b = int(np.argmin(u[m])), int(np.argmax(u[m]))
        order = np.roll(np.arange(n), -a)
        split = int(np.flatnonzero(order == b)[0])
        chains = [order[:split + 1], np.append(order[split:], a)]
        heights = []
        for chain in chains:
            uc, vc = u[m, chain], v[m, chain]
            k = np.argsort(uc, kind="stable")
            heights.append(np.interp(u[m], uc[k], vc[k]))
        mid[m] = (heights[0] + heights[1]) / 2
    return mid


# a station's section is kept when the blend of its neighbours misses it by more than this part of
# the yarn's height (the files stay small: most stations of a corrected yarn blend to 1e-3)
SECTION_TOL = 1e-3
# decimals [mm] the corrected sections' points keep (with a section tolerance > 0): 1e-9 mm, a
# hundred-thousandth of SECTION_TOL on a 0.1 mm yarn and a tenth of the 1e-8 mm to which serial and
# parallel runs agree; their shortest decimal form is then 40 % shorter in corrected.tg3 and .json
SECTION_DECIMALS = 9


def _heights(polys: np.ndarray) -> np.ndarray:
    return np.ptp(polys[..., 1], axis=1)


def sparse_sections(nodes: np.ndarray, polys: np.ndarray, periodic: bool, tol: float):
    """Sections at the stations (nodes) as PositionSections holding only the polygons that the
    linear blend of the kept ones (in TexGen's position: the fraction of the length along the
    straight segments between nodes) would miss by more than tol [mm] (Douglas-Peucker on the
    stations); NodeSections when nearly all are needed. With tol > 0 the points are rounded to
    SECTION_DECIMALS (tol = 0 keeps every station's polygon as it is)."""
    if tol > 0:
        polys = np.round(polys, SECTION_DECIMALS)
    seg = np.linalg.norm(np.diff(nodes, axis=0), axis=1)
    frac = np.concatenate(([0.0], np.cumsum(seg))) / np.sum(seg)
    last = len(polys) - 1 if periodic else len(polys)  # a periodic yarn's last station is its first
    keep = np.zeros(len(polys), bool)
    keep[0] = keep[len(polys) - 1] = True
    stack = [(0, len(polys) - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        u = (frac[a + 1:b] - frac[a]) / (frac[b] - frac[a])
        blended = polys[a] + (polys[b] - polys[a]) * u[:, None, None]
        miss = np.max(np.linalg.norm(polys[a + 1:b] - blended, axis=2), axis=1)
        k = int(np.argmax(miss))
        if miss[k] > tol:
            keep[a + 1 + k] = True
            stack += [(a, a + 1 + k), (a + 1 + k, b)]
    kept = np.flatnonzero(keep[:last]) if periodic else np.flatnonzero(keep)
    if len(kept) > 0.8 * len(polys):
        return NodeSections(tuple(Polygon(tuple(map(tuple, p))) for p in polys))
    return PositionSections(tuple(float(frac[k]) for k in kept),
                            tuple(Polygon(tuple(map(tuple, polys[k]))) for k in kept))


def _areas(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Signed areas of the polygons (u[k], v[k]) (anticlockwise positive)."""
    return 0.5 * np.sum(u * np.roll(v, -1, axis=1) - np.roll(u, -1, axis=1) * v, axis=1)


def _centred(probe: Yarn, pos: np.ndarray, polys: np.ndarray, periodic: bool,
             passes: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The stations moved onto their sections' centroids, the sections cut from the same surface
    in the planes normal to the new path, and thickened back to their area.

    A section moved point by point with the plate bends with it: across a crossing yarn's curve
    its flanks rise or fall and its centroid leaves the path (0.056 mm of a 0.36 mm section on
    the polygon weave). A tube swept along a path of curvature k holds A (1 - k . c) per unit of
    path length, c the centroid's offset (Pappus): flanks up over a crest, down under a trough
    grew the plain polygon weave's volume per length by 3 %. With its path through the centroids
    a yarn holds its sections' area per length, and its length is its fibres'. Only the offset
    along the section's up vector is taken: the path's curvature lies in that plane, and the
    across offset is noise of a few um where a crown meets a leg, which put wiggles into the path.

    The new path turns by dc/ds against the old: a section merely turned with it would move its
    flanks along the path (0.02 mm on the jammed plain weave, where the flanks drape more steeply
    than the path). Instead the surface is kept: each new section is where the plane normal to
    the new path cuts the old tube (_cut). That oblique cut holds A cos(dc/ds): the section is
    thickened back to A about its centroid (by dc/ds squared over 2, at most 0.7 % on the
    polygon weave)."""
    if np.max(np.abs(polygon_centroids(polys)[:, 1])) < 1e-12:  # on the path already (a leg, a straight yarn)
        return pos, polys
    target = _areas(polys[..., 0], polys[..., 1])
    _, _, up, side = probe.frames(np.arange(len(pos), dtype=float))
    surface = (probe, polys)
    moved, frame, shift = pos, (up, side), np.zeros(len(pos))
    for _ in range(passes):
        c = polygon_centroids(polys)
        moved = moved + c[:, 1:] * frame[0]
        shift += c[:, 1]
        if periodic:  # the last station repeats the first
            moved[-1] = moved[0] + (pos[-1] - pos[0])
        _, tan, up, side = replace(probe, nodes=moved).frames(np.arange(len(pos), dtype=float))
        frame = (up, side)
        cut = _cut(*surface, moved, tan) - moved[:, None, :]
        polys = np.stack((np.einsum("mkj,mj->mk", cut, side), np.einsum("mkj,mj->mk", cut, up)), axis=-1)
    # where the old tube folds, a plane may cut it more than once and the cut cross itself: the
    # section is then only turned with the path (seen at a binder's crown end in an input whose
    # legs overlap their neighbours)
    crossed = self_intersecting(polys)
    polys[crossed] = surface[1][crossed] - np.stack((np.zeros(crossed.sum()), shift[crossed]), axis=-1)[:, None, :]
    c = polygon_centroids(polys)
    grow = (target / _areas(polys[..., 0], polys[..., 1]))[:, None]
    polys = np.stack((polys[..., 0], c[:, 1:] + (polys[..., 1] - c[:, 1:]) * grow), axis=-1)
    if periodic:
        polys[-1] = polys[0]
    return moved, polys


def _cut(probe: Yarn, polys: np.ndarray, at: np.ndarray, normal: np.ndarray, iterations: int = 4,
         fine: int = 32) -> np.ndarray:
    """Where the planes through at[m] normal to normal[m] (M, 3) cut the tube of the path `probe`
    (its frames) carrying the polygons `polys` (M, K, 2) at its nodes, blended linearly between
    them (the surface the corrected yarn would have): per point of each section, the crossing of
    its line along the tube nearest node m (secant steps from the node, within one node of it;
    the path and its frames taken at `fine` samples per node interval, linear between)."""
    M, K = polys.shape[:2]
    n = probe.n_segments
    grid = np.arange(M)[:, None] + np.linspace(-1.0, 1.0, 2 * fine + 1)[None, :]  # (M, G)
    wrap = np.floor(grid / n) if probe.periodic else np.zeros_like(grid)
    grid = grid - wrap * n if probe.periodic else np.clip(grid, 0, n)
    frames = [a.reshape(M, -1, 3) for a in probe.frames(grid.ravel())]
    frames[0] = frames[0] + wrap[..., None] * (probe.nodes[-1] - probe.nodes[0])
    # position, side and up side by side, and their steps to the next sample (and the polygons'
    # to the next node), taken once: point() then gathers two rows where it gathered six (the
    # same numbers: a[j + 1] - a[j] is the step; _cut was half the correction's time on satin4)
    table = np.concatenate([frames[k].reshape(-1, 3) for k in (0, 3, 2)], axis=1)
    step, poly_step = table[1:] - table[:-1], polys[1:] - polys[:-1]
    rows, k = np.arange(M)[:, None], np.arange(K)[None, :]

    def point(x: np.ndarray) -> np.ndarray:  # (M, K, 3) on the tube at parameters node m + x[m, k]
        g = (x + 1.0) * fine
        j = np.minimum(np.floor(g).astype(int), 2 * fine - 1)
        f = (g - j)[..., None]
        flat = rows * (2 * fine + 1) + j
        on = table[flat] + step[flat] * f  # position, side, up
        s = np.clip(rows + x, 0, M - 1) if not probe.periodic else rows + x
        s = np.mod(s, n) if probe.periodic else s
        i = np.minimum(np.floor(s).astype(int), n - 1)
        sec = polys[i, k] + poly_step[i, k] * (s - i)[..., None]
        return on[..., 0:3] + sec[..., :1] * on[..., 3:6] + sec[..., 1:] * on[..., 6:9]

    def offset(x: np.ndarray) -> np.ndarray:
        return np.einsum("mkj,mj->mk", point(x) - at[:, None, :], normal)

    x0, x1 = np.zeros((M, K)), np.full((M, K), 0.1)
    f0, f1 = offset(x0), offset(x1)
    for _ in range(iterations):
        if np.max(np.abs(f1)) < 1e-13:
            break
        slope = (f1 - f0) / np.where(x1 != x0, x1 - x0, 1.0)
        x2 = np.clip(np.where(slope != 0, x1 - f1 / np.where(slope != 0, slope, 1.0), x1), -1.0, 1.0)
        x0, f0, x1 = x1, f1, x2
        f1 = offset(x1)
    return point(x1)


def corrected_textile(textile: Textile, w: list, spacing: float, n_points: int = 32, split=None,
                      flats: list | None = None) -> Textile:
    """The textile with every yarn moved by its displacement (w[k] for plate yarn k: yarn k itself,
    or with `split` (legs.Split) the crown k of the plate model); flats[k]: yarn k's flattening
    (Flat; yarns that are one plate); collective."""
    if split is None or not split.any:
        displacements = list(w)
    else:
        displacements = [None] * len(textile.yarns)
        for k, crown in enumerate(split.crowns):
            if crown.whole:
                displacements[crown.yarn] = w[k]
            else:
                if displacements[crown.yarn] is None:
                    displacements[crown.yarn] = _Crowns(textile.yarns[crown.yarn], [], textile.cell)
                displacements[crown.yarn].pieces.append((crown, w[k], split.plate.yarns[k]))
    most = budgets(textile.yarns, spacing, n_points)
    for y, bound in zip(textile.yarns, most):
        if bound is not None:
            log.warning("%s: corrected at %d stations, %.3g mm apart on average instead of at most %g mm: the "
                        "corrected yarn has a master node at each, and a model is read back with at most %d per "
                        "yarn, %d in all and %.3g surface points (limits.py)", y.name, bound,
                        y.length() / (bound - 1), spacing, MAX_NODES_PER_YARN, MAX_NODES, MAX_SURFACE_POINTS)
    flats = flats or [None] * len(textile.yarns)
    yarns = [corrected_yarn(textile, i, wi, spacing, n_points, most=bound, flat=flat)
             for i, (wi, bound, flat) in enumerate(zip(displacements, most, flats))]
    c = textile.cell
    z = np.concatenate([y.nodes[:, 2] for y in yarns])
    heights = [max(s.height for s in y.section.sections()) for y in yarns]
    lo, hi = z.min() - max(heights), z.max() + max(heights)
    z_range = None if c.z_range is None else (min(c.z_range[0], lo), max(c.z_range[1], hi))
    # its surfaces need no finer stations than its own (one polygon per station of the correction)
    resolution = replace(textile.resolution, spacing=max(textile.resolution.spacing, spacing),
                         section_points=n_points)
    corrected = Textile(replace(c, z_range=z_range), yarns, name=f"{textile.name}_corrected", resolution=resolution,
                        plies=textile.plies, ply_sizes=textile.ply_sizes)
    readable(corrected)
    return corrected


def readable(textile: Textile) -> None:
    """Refuse (GeometryError naming the yarn, the quantity and the bound) a model the pipeline made
    that its readers would refuse: as a .tg3 (read with the default resolution) or as our model
    file (with its own). budgets() keeps corrected models within; this says where one is not."""
    for resolution in (textile.resolution, Resolution()):
        try:
            Textile(textile.cell, textile.yarns, textile.name, resolution).check_size()
        except TextileError as e:
            raise GeometryError(f"the corrected model would not be read back: {e}") from None
