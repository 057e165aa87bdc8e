"""Width spreading under compaction (DESIGN.md 5b): a yarn pressed thinner spreads sideways into
the room its neighbours leave it.

The rule, stated. A yarn pressed to r of its model's thickness (its plate's volume at the end of
the compaction over its rest shape's, pipeline.Run.volume_ratio, over its spread f) is spread by
f = r^(-s), s the spreading exponent (CompactionTarget.spreading [-]: 0 keeps the width). It is
never narrowed, and never wider than its `room`: the factor at which its edge would meet the edge
of a yarn beside it, both spread alike about their centrelines, times (1 - ROOM_MARGIN). Beside
it: parallel in the plane within 20 degrees, at heights that overlap, and apart in plan at the
model's widths (yarns that overlap in plan lie one above the other; crossing yarns do not count).
Lateral contact is not modelled: the room is read from the model's centrelines, not solved for.

A spread yarn is its model's yarn with every section f times as wide and 1/f times as high
(`widen`; a lenticular one as high as keeps its area): the same area, so the same fibres at the
same fibre fraction at rest, and the compaction law (its phi0, the bundle's) unchanged. Pressed,
its fibre fraction rises only as it thins beyond that rest shape.

The spread fabric is meshed, solved and pressed again from its rest state (its footprints
changed, so nothing of the last round's mesh carries over). The rounds (`Rounds`: secant steps
to the widths' fixed point) end when the widths a round asks for are within ROUND_TOLERANCE of
those it was pressed at.
"""

import logging
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from scipy.optimize import brentq

from textile_fenicsx.common.errors import MeshError, SolverError, TextileError
from textile_fenicsx.model.fibres import Fibres
from textile_fenicsx.model.sections import Ellipse, Flat, Hybrid, Lenticular, Polygon, PowerEllipse, Section
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.model.yarn_sections import ConstantSection, NodeSections, PositionSections
from textile_fenicsx.pipeline.compaction import CompactionTarget, yarn_fibre_areas
from textile_fenicsx.pipeline.runs import Run

__all__ = ["MAX_ROUNDS", "ROOM_MARGIN", "ROUND_TOLERANCE", "Rounds", "room", "spread", "widen"]

log = logging.getLogger(__name__)

# The rounds (each a whole run: mesh, solve, compaction) end when the widths a round asks for, or
# the bracket on them, are within ROUND_TOLERANCE [-] (Rounds), or after MAX_ROUNDS.
ROUND_TOLERANCE = 0.01
MAX_ROUNDS = 6

# The share of the room between two yarns side by side that a spreading leaves free [-]: the
# spread yarns' edges stay apart, and two yarns spaced s apart spread to at most 0.9 s between
# them. Spread to 0.98 of the room, the loose plain weave's yarns were jammed (its densest node at
# the maximum packing at 0.08 MPa), and the next round's energy was not convex at their corners, as
# the jammed weaves' at a coarse mesh (docs/sweep.md).
ROOM_MARGIN = 0.1
# Parallel in the plane: tangents within this angle [deg] (crossing yarns are about 90 apart).
PARALLEL_DEG = 20.0
SAMPLES_PER_SEGMENT = 16
SECTION_POINTS = 32


def _widened_section(section: Section, f: float) -> Section:
    """The section stretched by f along the side (s) and by 1/f along up (u): its area kept (a
    lenticular section stays two circular arcs, f times as wide, as high as keeps its area)."""
    if isinstance(section, Polygon):
        return Polygon(tuple(map(tuple, np.asarray(section.vertices) * (f, 1 / f))))
    if isinstance(section, Hybrid):
        return replace(section, pieces=tuple(_widened_section(p, f) for p in section.pieces))
    if isinstance(section, Flat):
        return replace(section, width=section.width * f)
    if isinstance(section, Lenticular):  # circular arcs stretched are not circular: the height that keeps the area
        lens = section

        def lens_of(h: float) -> Lenticular:
            return replace(lens, width=lens.width * f, height=h, distortion=lens.distortion * h / lens.height)

        return lens_of(brentq(lambda h: lens_of(h).area() - lens.area(), lens.height / f**2, lens.height, xtol=1e-15))
    assert isinstance(section, (Ellipse, PowerEllipse)), section
    return replace(section, width=section.width * f, height=section.height / f)


def _widened_sections(sections, f: float):
    if isinstance(sections, ConstantSection):
        return ConstantSection(_widened_section(sections.section, f))
    if isinstance(sections, NodeSections):
        return replace(sections, at_nodes=tuple(_widened_section(x, f) for x in sections.at_nodes),
                       mid=tuple((k, t, _widened_section(x, f)) for k, t, x in sections.mid))
    assert isinstance(sections, PositionSections)
    return replace(sections, at_positions=tuple(_widened_section(x, f) for x in sections.at_positions))


def widen(textile: Textile, factors: np.ndarray, fibre_areas: list[float]) -> Textile:
    """The textile with yarn i's sections factors[i] times as wide and 1 / factors[i] times as high,
    each yarn carrying its fibre area fibre_areas[i] [mm^2] (the model's, to the last bit)."""
    yarns = [replace(y, section=_widened_sections(y.section, float(f)),
                     fibres=y.fibres if y.fibres is not None and y.fibres.fibre_area() else Fibres(area=a))
             for y, f, a in zip(textile.yarns, factors, fibre_areas)]
    return replace(textile, yarns=yarns)


def _samples(textile: Textile, i: int):
    """Yarn i sampled along its centreline: positions (M, 3), in-plane unit tangents and sides
    (M, 2), and its section's extents along the side and up: (M, 2) each, (least, largest) [mm]."""
    y = textile.yarns[i]
    s = np.linspace(0, y.n_segments, y.n_segments * SAMPLES_PER_SEGMENT, endpoint=False)
    pos, tan, up, side = y.frames(s)
    sec = y.section_points(s, SECTION_POINTS)
    plane_t = tan[:, :2] / np.maximum(np.linalg.norm(tan[:, :2], axis=1, keepdims=True), 1e-12)
    normal = np.column_stack((-plane_t[:, 1], plane_t[:, 0]))
    # a section point (a, b) lies at pos + a side + b up: its offset along the in-plane normal and in z
    across = sec[..., 0] * (side[:, :2] * normal).sum(axis=1)[:, None] \
        + sec[..., 1] * (up[:, :2] * normal).sum(axis=1)[:, None]
    height = sec[..., 0] * side[:, 2:3] + sec[..., 1] * up[:, 2:3]
    return (pos, plane_t, normal, np.column_stack((across.min(axis=1), across.max(axis=1))),
            np.column_stack((height.min(axis=1), height.max(axis=1))))


def room(textile: Textile) -> np.ndarray:
    """Per yarn the largest width factor [-] before its edge meets a yarn beside it (module
    docstring), over every pair of yarns and their periodic images; inf where no yarn lies beside
    it. Deterministic, so every rank computes the same."""
    data = [_samples(textile, i) for i in range(len(textile.yarns))]
    shifts = [np.zeros(2)]
    if textile.cell.periodic:
        r = textile.cell.repeats[:, :2]
        shifts = [a * r[0] + b * r[1] for a in (-1, 0, 1) for b in (-1, 0, 1)]
    cos_parallel = np.cos(np.radians(PARALLEL_DEG))
    out = np.full(len(data), np.inf)
    for i, (p, t, n, ext, z) in enumerate(data):
        for j, (q, tq, nq, extq, zq) in enumerate(data):
            # what does not depend on the periodic image: the samples' spacing along j, which pairs
            # of samples run parallel at heights that overlap, and j's extent along i's normal (its
            # own side may point either way)
            step = np.max(np.linalg.norm(np.diff(q[:, :2], axis=0), axis=1), initial=0.0)
            zi, zj = p[:, 2:3] + z[:, None, :], q[None, :, 2:3] + zq[None, :, :]
            level = (np.abs(t @ tq.T) >= cos_parallel) & \
                (np.minimum(zi[..., 1], zj[..., 1]) > np.maximum(zi[..., 0], zj[..., 0]))
            if not np.any(level):
                continue
            sign = np.sign(n @ nq.T)
            lo_j = np.where(sign > 0, extq[None, :, 0], -extq[None, :, 1])
            hi_j = np.where(sign > 0, extq[None, :, 1], -extq[None, :, 0])
            for shift in shifts:
                if i == j and not np.any(shift):
                    continue
                d = q[None, :, :2] + shift - p[:, None, :2]  # (Mi, Mj, 2)
                along = np.einsum("ik,ijk->ij", t, d)
                across = np.einsum("ik,ijk->ij", n, d)
                beside = level & (np.abs(along) <= step)
                if not np.any(beside):
                    continue
                # j to the +n side: i's top edge ext[:,1] meets j's low edge across + lo_j; else the other way
                reach = np.where(across > 0, ext[:, 1:2] - lo_j, hi_j - ext[:, 0:1])
                with np.errstate(divide="ignore", invalid="ignore"):
                    f = np.where(beside & (reach > 0), np.abs(across) / reach, np.inf)
                f[f < 1] = np.inf  # overlapping in the plane already: one above the other (a ply, its own path)
                out[i] = min(out[i], float(f.min()))
    return out * (1 - ROOM_MARGIN)


class Rounds:
    """The widths' fixed point f = g(f), per yarn: g the factors a round pressed at widths f asks
    for (r^(-s), kept within [1, room] here). The first step is g itself; the next ones are
    secant steps on h = g(f) - f, kept inside the bracket of widths where h changed sign (bisected
    where a step leaves it) and within [1, room] (a step beyond the room, where no width yet asked
    for less, goes to it). A plain iteration crept to the loose plain weave's widths by 0.6 of the
    way a round; and where the target is reachable only from some width on, h jumps there (a round
    that stops short asks for more, one that reaches the target for less), so the fixed point is
    that edge, which the bracket closes on. Settled when the widths a round asks for, or the
    bracket, are within ROUND_TOLERANCE."""

    def __init__(self, rooms: np.ndarray):
        self.rooms = np.maximum(rooms, 1.0)
        self.widths: list[np.ndarray] = [np.ones(len(rooms))]
        self.asked: list[np.ndarray] = []
        self.low: np.ndarray = np.ones(len(rooms))
        self.high: np.ndarray = self.rooms.copy()
        self.bracketed = np.zeros(len(rooms), bool)  # high is a width that asked for less, not the room

    def next(self, asked: np.ndarray) -> tuple[np.ndarray, float]:
        """The widths for the next round, and how far the last round's are from settled [-]."""
        f, asked = self.widths[-1], np.clip(asked, 1.0, self.rooms)
        h = asked - f
        self.low = np.where(h > 0, np.maximum(self.low, f), self.low)
        self.high = np.where(h < 0, np.minimum(self.high, f), self.high)
        self.bracketed |= h < 0
        guess: np.ndarray = asked
        if self.asked:
            f0 = self.widths[-2]
            slope = h - (self.asked[-1] - f0)
            with np.errstate(divide="ignore", invalid="ignore"):
                guess = np.where(np.abs(slope) > 1e-9, f - h * (f - f0) / slope, asked)
        inside = (guess > self.low) & (guess <= self.high)
        beyond_room = (guess > self.high) & ~self.bracketed  # the room itself may be the fixed point
        guess = np.where(inside, guess, np.where(beyond_room, self.high, (self.low + self.high) / 2))
        self.asked.append(asked)
        self.widths.append(np.asarray(np.clip(guess, 1.0, self.rooms), float))
        change = min(float(np.max(np.abs(asked / f - 1))), float(np.max(self.high / self.low - 1)))
        return self.widths[-1], change


def spread(result: Run, textile: Textile, target: CompactionTarget, solve: Callable[[Textile], Run]) -> Run:
    """The rounds (module docstring) after `result`, the run of the model as given: solve(model)
    runs a spread model (pipeline: meshed again where it fails, Settings.remesh). The Run returned
    is the last round's, or where that one stopped short of the target, the last that reached it;
    its `spreading` holds the widths (collective: every rank takes the same steps)."""

    rooms, areas = room(textile), yarn_fibre_areas(textile)
    rounds = Rounds(rooms)
    widths, spent = rounds.widths[0], result.times["total"]
    reached: tuple | None = None  # the last round whose compaction reached its target: (round, widths, run)
    for k in range(1, MAX_ROUNDS + 1):
        curve = result.compaction
        if result.volume_ratio is None or curve is None:  # nothing was pressed: nothing spreads
            break
        if curve.reason is None:
            reached = (k, widths, result)
        # each yarn's thickness over its model's: its plate's volume ratio over the spread's 1/f of height,
        # and where the compaction stopped short, scaled by the target over the last thickness reached
        # (the flattening the target asks: else a round only repeats the widths at which the last stopped)
        reach = 1.0 if curve.reason is None else curve.target / curve.thickness[-1]
        thinning = reach * np.asarray(result.volume_ratio) / widths
        new, change = rounds.next(thinning ** -target.spreading)
        asked = rounds.asked[-1]
        log.info("spreading: round %d at width factors %.4f-%.4f pressed the yarns to %.3f-%.3f of their model's "
                 "thickness, which asks for %.4f-%.4f (room %.4f at least): %.2f %% apart", k, widths.min(),
                 widths.max(), thinning.min(), thinning.max(), asked.min(), asked.max(), rooms.min(), 100 * change)
        if change <= ROUND_TOLERANCE:
            break
        if k == MAX_ROUNDS:
            log.warning("spreading: after %d rounds the widths are still %.2f %% from those the last round asks "
                        "for", MAX_ROUNDS, 100 * change)
            break
        start = time.perf_counter()
        try:
            again = solve(widen(textile, new, areas))
        except (TextileError, SolverError, MeshError) as e:
            why = str(e)
        else:
            why = "" if again.converged else again.solution.reason
        spent += time.perf_counter() - start
        if why:  # the spread fabric could not be solved: the rounds end here
            log.warning("spreading: round %d at width factors %.4f-%.4f failed (%s)", k + 1, new.min(), new.max(), why)
            break
        widths, result = new, again
    if reached is not None and result.compaction is not None and result.compaction.reason is not None:
        log.warning("spreading: the last round stopped short of the target; round %d, which reached it, is kept",
                    reached[0])
        _, widths, result = reached
    result.spreading = [float(f) for f in widths]
    result.times["total"] = spent
    return result
