"""Steep stretches of yarns: a binder's legs are not plates (DESIGN.md 4.6 and issue 14).

A projected plate describes a yarn by its mid-height over the plane; where the yarn runs (nearly)
vertically, as TexGen's orthogonal and interlock binders do between weft columns, its plan is a
strip as narrow as the yarn is thick and its "plate" is a column. So before meshing, every yarn is
cut where its centreline is steeper than STEEP, or turns back against its own direction in plan
(a loop: two heights over one place): the stretches between cuts that are neither are the crowns,
each a plate of its own (a non-periodic yarn of the plate model with the original's stations,
sections and up vectors, repeated by the cell like the original); the steep stretches are the
legs, left out of the plates. A leg carries the yarn's tension (sigma1 per unit width)
from one crown's end to the next one's start: on each crown end it is a vertical force, down where
the leg goes down, spread over the crown within one seed of the end. After the solve the yarn is
put together again (correct.py): crowns move with their plates, each leg's stations move by the
displacements of its two crown ends, interpolated along the leg, and keep their sections.
"""

import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import brentq

from textile_fenicsx.correction.loops import unlooped
from textile_fenicsx.model.sections import Polygon
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.model.yarn import NodeSections, Yarn

__all__ = ["CROSSING_CUT_AT_SIDE", "STEEP", "Crown", "Split", "plate_model", "split_steep"]

log = logging.getLogger(__name__)

# slope |dz| / |dxy| above which a stretch of a yarn is a leg (72 degrees)
STEEP = 3.0

# A crown that crosses a cell side within a quarter of the seed of its end is cut back from the side
# (False), not at it (True). At it, the wide-binder orthogonal weaves' corrected binders, whose
# crowns cross the side by 0.026 mm, came out 0.0014 mm deep in a weft (0.00026 cut back; limit
# 0.003) and the 1.375 mm binder folded 0.03-0.10 % of its volume at its corner there, at the limit
# of 0.1 %, as gmsh's mesh moved with the ends' round-off (6 060 or 6 064 cells)
CROSSING_CUT_AT_SIDE = False


@dataclass(frozen=True)
class Crown:
    """Plate yarn k of the plate model: yarn `yarn` of the textile over path parameters [s0, s1]
    (s1 - s0 may run past the yarn's last node: a periodic yarn's crown can wrap); s0 = s1 = None
    for a yarn taken whole. load_start, load_end: the vertical force of a leg on the crown's start
    and end [N] (0 where no leg joins)."""

    yarn: int
    s0: float | None = None
    s1: float | None = None
    load_start: float = 0.0
    load_end: float = 0.0

    @property
    def whole(self) -> bool:
        return self.s0 is None


@dataclass(frozen=True)
class Split:
    """The plate model of a textile: `plate` (its yarns are the textile's, with steep ones cut into
    crowns) and, per plate yarn, where it comes from. `textile` is the one the plates were made
    from: the model without the loops of the yarns `unlooped` (loops.py)."""

    textile: Textile
    plate: Textile
    crowns: tuple
    unlooped: tuple = ()

    @property
    def any(self) -> bool:
        return any(not c.whole for c in self.crowns)

    @property
    def binders(self) -> list[int]:
        """The yarns cut into crowns or without their loops: those whose corrected legs and bends
        are fitted (leg_fit.py, bend_fit.py)."""
        return sorted({c.yarn for c in self.crowns if not c.whole} | set(self.unlooped))


def _path(yarn: Yarn, s: np.ndarray):
    """Frames at parameters s that may run past the last node of a periodic yarn."""
    n = yarn.n_segments
    wraps = np.floor(s / n)
    pos, tan, up, side = yarn.frames(s - wraps * n)
    return pos + wraps[:, None] * yarn.period, tan, up, side


def leg_stations(yarn: Yarn, tan: np.ndarray) -> np.ndarray:
    """Where a yarn with unit tangents `tan` (M, 3) at stations is no plate: steeper than STEEP, or
    running back against its own direction in plan (the yarn's period, or first to last node). A
    plate is a height over the plane, and a yarn that turns back over itself has two there: TexGen's
    layer-to-layer weave with a binder thicker than the gap between weft columns puts a binder node
    past the next one (x 11.027, 11.24, 11.16 mm), a loop at the leg."""
    steep = np.abs(tan[:, 2]) > STEEP * np.linalg.norm(tan[:, :2], axis=1)
    ahead = (yarn.period if yarn.periodic else yarn.nodes[-1] - yarn.nodes[0])[:2]
    if np.linalg.norm(ahead) > 0:
        steep |= tan[:, :2] @ ahead < 0
    return steep


def steep_runs(yarn: Yarn, spacing: float) -> list[tuple[float, float]]:
    """The yarn's crowns as parameter intervals [(s0, s1), ...], or [] when no station is a leg's
    (`leg_stations`)."""
    s = yarn.stations(spacing)
    if yarn.periodic:
        s = s[:-1]
    _, tan = yarn.centreline(s)
    steep = leg_stations(yarn, tan)
    if not np.any(steep) or np.all(steep):
        return []
    n = yarn.n_segments
    if yarn.periodic:  # start the walk on a steep station, so that no crown wraps in the walk
        k0 = int(np.argmax(steep))
        order = np.r_[np.arange(k0, len(s)), np.arange(k0)]
        s_walk = np.where(order >= k0, s[order], s[order] + n)
        steep = steep[order]
    else:
        s_walk = s
    runs, start = [], None
    for k in range(len(s_walk)):
        if not steep[k] and start is None:
            start = k
        if (steep[k] or k == len(s_walk) - 1) and start is not None:
            end = k - 1 if steep[k] else k
            if end > start:
                runs.append((float(s_walk[start]), float(s_walk[end])))
            start = None
    return runs


def split_steep(textile: Textile, spacing: float) -> Split:
    """Cut every yarn with steep stretches into crowns (stations `spacing` mm apart)."""
    yarns, crowns = [], []
    for i, yarn in enumerate(textile.yarns):
        runs = steep_runs(yarn, spacing / 4)
        if not runs:
            yarns.append(yarn)
            crowns.append(Crown(i))
            continue
        pieces = []
        for k, (s0, s1) in enumerate(runs):
            s0, s1 = _clear_of_sides(textile, yarn, s0, s1, spacing / 2)
            yarns.append(_crown_yarn(textile, yarn, s0, s1, spacing, f"{yarn.name} crown {k}"))
            pieces.append([s0, s1])
        tension = [_leg_force(textile, yarn, a[1], b[0]) for a, b in zip(pieces, pieces[1:] + [
            [pieces[0][0] + yarn.n_segments, None]])]
        for k, (s0, s1) in enumerate(pieces):
            before = tension[k - 1] if yarn.periodic or k > 0 else 0.0
            after = tension[k] if yarn.periodic or k < len(pieces) - 1 else 0.0
            crowns.append(Crown(i, s0, s1, load_start=-before, load_end=after))
    cut = any(not c.whole for c in crowns)
    # a coupon's mesh is its unit cell's repeated, yarn by yarn: with cut yarns it is meshed whole
    plate = Textile(textile.cell, yarns, name=f"{textile.name}_plates" if cut else textile.name,
                    resolution=textile.resolution, tiling=None if cut else textile.tiling)
    return Split(textile, plate, tuple(crowns))


def plate_model(textile: Textile, seed: float) -> Split:
    """The plates every command meshes (mesh, solve, the bench): the textile without the loops of
    its master nodes (loops.py) and with its legs cut out (split_steep, stations seed / 2 apart),
    the yarns so cut named in the log."""
    textile, looped = unlooped(textile)
    split = split_steep(textile, seed / 2)
    if split.any:
        log.info("legs: %s cut into crowns where steeper than %g or turning back", ", ".join(
            sorted({textile.yarns[c.yarn].name for c in split.crowns if not c.whole})), STEEP)
    return replace(split, unlooped=looped)


def _clear_of_sides(textile: Textile, yarn: Yarn, s0: float, s1: float, margin: float) -> tuple[float, float]:
    """The crown [s0, s1] with each end that lies within `margin` of a cell side (in plan) moved onto
    the side where its path, beyond the end, meets it within `margin` (_onto_side), else shortened
    until it lies `margin` from every side. A plate's end that close to a side meets the side on one copy of the
    cell and not on the other (gmsh merges what lies within its tolerance), and a sliver of plate
    with nothing around it remains; an end on the side leaves none. Cut back, the crown lost its
    corner: TexGen's refined orthogonal weaves stand a leg on the side, and their crowns, cut back
    0.1 mm over the wefts' edges, were lifted there by the leg's pull (0.17 mm) while the leg,
    interpolated to them, ran through the edges (0.05 mm deep). The leg takes the stretch."""
    cell = textile.cell
    if not cell.periodic:
        return s0, s1
    s = np.linspace(s0, s1, 400)
    xy = _path(yarn, s)[0][:, :2]
    near = np.zeros(len(s), bool)
    for axis, lo, length in ((0, cell.bounds[0], cell.lx), (1, cell.bounds[2], cell.ly)):
        rel = np.mod(xy[:, axis] - lo, length)
        near |= (rel < margin) | (length - rel < margin)
    clear = np.flatnonzero(~near)
    if len(clear) == 0 or not (near[0] or near[-1]):
        return s0, s1
    start = _onto_side(textile, yarn, s0, s1, margin) if near[0] else s0
    end = _onto_side(textile, yarn, s1, s0, margin) if near[-1] else s1
    return (float(s[clear[0]]) if start is None else start), (float(s[clear[-1]]) if end is None else end)


def _onto_side(textile: Textile, yarn: Yarn, end: float, other: float, margin: float) -> float | None:
    """The parameter where the path meets a cell side within `margin` of plan length from a crown's
    end `end` (the crown runs towards `other`): beyond its end, into the leg, where that stretch
    climbs no steeper than STEEP on average (a leg that stands on the side: the crown reaches it);
    None where it meets none, or where the crown itself crosses the side first (cut there only with
    CROSSING_CUT_AT_SIDE)."""
    cell = textile.cell
    ahead = float(np.sign(other - end))
    for way, reach in ((ahead, min(1.0, abs(other - end))), (-ahead, 1.0)):  # the crown, then the leg
        s = end + way * np.linspace(0.0, reach, 801)
        pos = _path(yarn, s)[0]
        plan = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1))]
        first: tuple[int, int, float] | None = None  # (sample, axis, side line) of the first crossing
        for axis, lo, length in ((0, cell.bounds[0], cell.lx), (1, cell.bounds[2], cell.ly)):
            copy = np.floor((pos[:, axis] - lo) / length)
            crossings = np.flatnonzero((copy[1:] != copy[:-1]) & (plan[1:] <= margin))
            if len(crossings) and (first is None or crossings[0] < first[0]):
                c = int(crossings[0])
                first = (c, axis, float(lo + max(copy[c], copy[c + 1]) * length))
        if first is None:
            continue
        if way == ahead and not CROSSING_CUT_AT_SIDE:
            return None
        k, axis, line = first

        def off(t: float, axis: int = axis, line: float = line) -> float:  # from the side line
            return float(_path(yarn, np.array([t]))[0][0, axis] - line)

        at = float(brentq(off, min(s[k], s[k + 1]), max(s[k], s[k + 1]), xtol=1e-14))
        if way == ahead:
            return at
        rise = abs(_path(yarn, np.array([at]))[0][0, 2] - pos[0, 2])
        return at if rise <= STEEP * plan[k + 1] else None
    return None


def _crown_yarn(textile: Textile, yarn: Yarn, s0: float, s1: float, spacing: float, name: str) -> Yarn:
    """The stretch [s0, s1] of a yarn as a yarn of its own: stations as master nodes (cubic),
    the original's sections there as polygons, its up vectors; repeated like the original."""
    length = np.sum(np.linalg.norm(np.diff(_path(yarn, np.linspace(s0, s1, 64))[0], axis=0), axis=1))
    s = np.linspace(s0, s1, max(4, int(np.ceil(length / spacing)) + 1))
    pos, _, up, _ = _path(yarn, s)
    n = yarn.n_segments
    sections = yarn.section_points(s - np.floor(s / n) * n, textile.resolution.section_points)
    return Yarn(pos, NodeSections(tuple(Polygon(tuple(map(tuple, p))) for p in sections)), "cubic", periodic=False,
                repeats=yarn.repeats, ups=up, name=name, fibres=yarn.fibres)


def _leg_force(textile: Textile, yarn: Yarn, s_end: float, s_next: float) -> float:
    """The leg from s_end (a crown's end) to s_next (the next one's start): the vertical force it
    pulls the first crown's end with [N], sigma1 x the yarn's width being applied by the caller
    (here the signed width: negative where the leg goes down)."""
    z0, z1 = _path(yarn, np.array([s_end, s_next]))[0][:, 2]
    n = yarn.n_segments
    width = float(np.ptp(yarn.section_points(np.array([s_end - np.floor(s_end / n) * n]), 64)[0, :, 0]))
    return width * float(np.sign(z1 - z0))


def leg_loads(split: Split, ms, sigma1: float, radius: float) -> dict:
    """Per plate yarn with a leg at an end, its load [N/mm^2] as a function of the spatial
    coordinate (for ContactProblem's `loads`): sigma1 x width at each such end, spread evenly over
    the crown within `radius` of the end's centre (collective). The numbers are Constants, so that
    one compiled form serves every crown."""
    import ufl
    from mpi4py import MPI

    import dolfinx

    loads = {}
    for k, crown in enumerate(split.crowns):
        if crown.whole or (crown.load_start == 0 and crown.load_end == 0):
            continue
        y, plate_yarn = ms.yarns[k], split.plate.yarns[k]
        x = ufl.SpatialCoordinate(y.mesh)
        terms = []
        for point, force in ((plate_yarn.nodes[0], crown.load_start), (plate_yarn.nodes[-1], crown.load_end)):
            if force == 0:
                continue
            centre = dolfinx.fem.Constant(y.mesh, np.asarray(point[:2], dtype=float))
            near = _near(x, centre, dolfinx.fem.Constant(y.mesh, float(radius)), split.textile.cell)
            area = y.mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(near * y.dx)), op=MPI.SUM)
            if area > 0:
                terms.append(dolfinx.fem.Constant(y.mesh, sigma1 * force / area) * near)
        if terms:
            loads[k] = (lambda xx, terms=terms: sum(terms[1:], terms[0]))
    return loads


def _near(x, centre, radius, cell):
    """1 within `radius` of `centre` in plan (or of its periodic copies), else 0 (UFL)."""
    import ufl

    shifts = [(0.0, 0.0)]
    if cell.periodic:
        shifts = [(a * cell.lx, b * cell.ly) for a in (-1, 0, 1) for b in (-1, 0, 1)]
    inside = None
    for dx, dy in shifts:
        d2 = (x[0] - centre[0] - dx) ** 2 + (x[1] - centre[1] - dy) ** 2
        here = ufl.conditional(ufl.lt(d2, radius**2), 1.0, 0.0)
        inside = here if inside is None else ufl.max_value(inside, here)
    return inside
