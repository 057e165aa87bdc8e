"""Bends opened where a binder's sections fold over (after leg_fit; DESIGN.md 7c; issue 27, item 4).

A section swept along a path folds over itself on the inside of a bend tighter than the section
reaches there: the sections' areas then count a volume twice that space holds once (verify.tube).
The plates place a yarn's surface by vertical offsets, so where a binder's crown wraps the sharp
edge of a weft (an ellipse 2.58 x 0.3 mm has an edge radius of 0.017 mm) and turns into its leg,
its path turns as tightly as the weft's edge, and its 0.3 mm sections fold there.

So after the legs are fitted, a yarn cut into crowns (or without its loops, loops.py) whose
sections fold over (the check's own measure, verify.tube, more than FOLD_FLOOR of its volume) has
its stations next to the folds where a section reaches, on the inside of the bend, more than
BEND_RATIO of the bend's radius (the turn between the chords to its neighbours over their mean
length) opened, with BEND_PAD stations either side, by a small problem of its own:

- unknowns: a_k, the path's offset along the section's up vector (as in leg_fit);
- energy: sum_k ((a_{k-1} - 2 a_k + a_{k+1}) / h_k)^2, the kink of the change (h_k the section's
  height), with a = 0 at the stations beyond the stretch;
- constraints, nonlinear in a: at every station the section's reach up and down times the turn
  along up, and its least reach times the whole turn (the path may not double back), at most
  BEND_RATIO times the mean chord; no chord shorter than BEND_SPACING of what it was (the cubic
  through the stations kinks where two nearly meet); and along +-up, at the stations and three
  points between each two, no nearer the other yarns than leg_fit's probes allow less a probe
  step and leg_fit's margin (leg_fit.margin: the solve's least gap where that is more; a crown in
  contact may stay or leave, never go in).

scipy's SLSQP solves it, in units of the section's height. A stretch it cannot open is tried with
BEND_PAD more stations either side, BEND_WIDENINGS times, and is then left as it was (the check
names the fold). The sections turn with the path, which the probes along up do not see: so the
check's own overlap depth (vertical rays, on a grid of GUARD_STEP of the cell's side over the
stretch) may grow nowhere beyond REACH_TOL of the thinnest yarn's height; where it would, the
move is scaled back (BEND_SCALES), and the stretch is left as it was if none is clear. The
constraints hold at the stations, and the cubic between them may turn tighter: a move is kept
only where the yarn's swept-back volume (verify.tube, the check's measure) falls.

BEND_RATIO is below 1 because the corrected path is a cubic through the stations (one parameter
step per station) and turns between them more tightly than its chords do. Measured on the
wide-binder orthogonal weave (ortho_w2f3_binder1.0x0.3, its binders' swept-back volume 0.77 %
without this step, limit 0.1 %), the two binders keep 0.12 and 0.11 % at a ratio of 0.8, 0.047
and 0.039 % at 0.6, 0.029 and 0.009 % at 0.5 (paths moved 0.034 mm at most, no overlap added),
0.003 and 0.022 % at 0.4, and 0.11 and 0.19 % at 0.3, where the paths move up to 0.13 mm and the
guard scales most moves back. What it does not do: the weft's edge is not rounded, the other yarns
do not move, and the path does not feed back into the plates' solve.
"""

import logging
from dataclasses import replace

import numpy as np
from scipy.optimize import minimize

from textile_fenicsx.correction.leg_fit import (
    PROBE_STEPS,
    extents,
    margin,
    probes,
    rebuilt,
    runs,
    second_difference,
    unwrapped,
    walls,
)
from textile_fenicsx.correction.verify import Tolerances, tube
from textile_fenicsx.model.metrics import coverage_depth
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.model.yarn import Yarn

__all__ = ["BEND_RATIO", "open_bends"]

log = logging.getLogger(__name__)

# a yarn that folds less than this (of its volume: a tenth of the check's limit) is left as it is
FOLD_FLOOR = 0.1 * Tolerances().fold
# the most a section may reach on the inside of a bend, in radii of the bend at a station
BEND_RATIO = 0.5
# stations either side of a tight one that may move with it, and the times a stretch that cannot
# open is tried again with BEND_PAD more either side
BEND_PAD = 5
BEND_WIDENINGS = 2
# the least a station's distance to the next may shrink to, of what it was
BEND_SPACING = 0.5
# the fractions of a stretch's move tried, in turn, until its sections reach into no neighbour
BEND_SCALES = (1.0, 0.75, 0.5, 0.25)
# the guard: the check's overlap depth, on a grid of this step (of the cell's side: half the
# check's), may grow nowhere beyond REACH_TOL of the thinnest yarn's height (half the check's limit)
GUARD_STEP = 0.0025
REACH_TOL = 0.005


def _bends(points: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, ...]:
    """At the inner points of a polyline (M, 3): its turn (the change of the unit chord, about the
    turning angle in radians) along up (signed) and in all (its length), and the mean of the two
    chords."""
    chords = np.diff(points, axis=0)
    length = np.linalg.norm(chords, axis=1)
    turn = np.diff(chords / length[:, None], axis=0)
    return np.einsum("ij,ij->i", turn, up), np.linalg.norm(turn, axis=1), 0.5 * (length[1:] + length[:-1])


def _with_offsets(yarn: Yarn, n: int, pos, up, sec, a) -> Yarn:
    """The yarn through its stations moved by a along their up vectors, with the same sections."""
    return rebuilt(yarn, n, pos + a[:, None] * up, sec)


def _grid(yarn: Yarn, q: np.ndarray, n_points: int, step: float) -> np.ndarray:
    """In-plane points (M, 2) on a grid of this step [mm] over the yarn's sections at parameters q,
    widened by a section's width either side."""
    qpos, _, qup, qside = yarn.frames(q)
    qsec = yarn.section_points(q, n_points)
    xy = (qpos[:, None] + qsec[..., :1] * qside[:, None] + qsec[..., 1:] * qup[:, None])[..., :2].reshape(-1, 2)
    pad = float(np.max(np.ptp(qsec[..., 0], axis=1)))
    lo, hi = xy.min(axis=0) - pad, xy.max(axis=0) + pad
    gx, gy = (np.arange(np.floor(lo[k] / step), np.ceil(hi[k] / step) + 1) * step for k in (0, 1))
    return np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)


def _depths(textile: Textile, i: int, yarn: Yarn, grid: np.ndarray) -> np.ndarray:
    """The check's overlap depth at the grid's points (metrics.coverage_depth: along vertical rays,
    the z covered by two yarns or more), with yarn i as given."""
    yarns = list(textile.yarns)
    yarns[i] = yarn
    col = replace(textile, yarns=yarns).columns(grid)
    return coverage_depth(len(grid), col.point, col.bottom, col.top)


def _opened_yarn(textile: Textile, i: int, n_points: int, tol: float, gap: float) -> tuple[Yarn, int, int]:
    """Yarn i with its tight bends opened (or as it was); stations moved and stretches left tight."""
    yarn = textile.yarns[i]
    n = len(yarn.nodes) - (1 if yarn.periodic else 0)
    pos, _, up, _ = yarn.frames(np.arange(n, dtype=float))
    sec = yarn.section_points(np.arange(n, dtype=float), n_points)
    reach = extents(sec)

    def chain(k: np.ndarray, a: np.ndarray) -> np.ndarray:  # stations k (unwrapped: -1 .. 2 n - 1), moved by a
        p = pos + a[:, None] * up
        return p[k % n] + (k // n)[:, None] * yarn.period if yarn.periodic else p[k]

    inner = np.arange(1, n - 1) if not yarn.periodic else np.arange(n)
    ends = np.concatenate(([inner[0] - 1], inner, [inner[-1] + 1]))
    turn, _, length = _bends(chain(ends, np.zeros(n)), up[inner])
    excess = np.zeros(n)  # how many times too tight each station's bend is
    excess[inner] = np.maximum(turn * reach[0][inner], -turn * reach[1][inner]) / (BEND_RATIO * length)
    swept = tube(yarn, textile.resolution)  # where the check finds the sections folding over
    if swept.folded <= FOLD_FLOOR * swept.volume:
        return yarn, 0, 0
    folds = np.zeros(n, bool)
    folds[np.floor(swept.s[:-1][swept.back > 0]).astype(int) % n] = True
    folds |= np.roll(folds, 1) | np.roll(folds, -1)
    tight = (excess > 1) & folds
    if not tight.any():
        return yarn, 0, 0
    mask = tight.copy()
    for k in np.flatnonzero(tight):
        mask[(k + np.arange(-BEND_PAD, BEND_PAD + 1)) % n] = True
    if not yarn.periodic:
        mask[0] = mask[-1] = False  # a free end is not moved
    elif mask.all():  # the stretches join round the yarn: the station farthest from a tight one stays
        k = np.arange(n)
        gap = np.abs(k[:, None] - np.flatnonzero(tight)[None])
        mask[int(np.argmax(np.min(np.minimum(gap, n - gap), axis=1)))] = False
    a, left = np.zeros(n), 0
    for run in runs(mask):
        for wider in range(BEND_WIDENINGS + 1):  # a bend too tight for its stretch gets a longer one
            stretch = _widened(run, wider * BEND_PAD, n, yarn.periodic)
            opened = _opened_run(textile, i, yarn, stretch, n, n_points, a, (pos, up, sec, reach), chain, (tol, gap))
            if opened is not None:
                a = opened
                break
        else:
            left += 1
    moved = int(np.sum(np.abs(a) > 0))
    if not moved:
        return yarn, 0, left
    return _with_offsets(yarn, n, pos, up, sec, a), moved, left


def _widened(run: np.ndarray, by: int, n: int, periodic: bool) -> np.ndarray:
    """The stretch of stations run (in order, may wrap) with `by` more either side: at most all
    but one station of a periodic yarn, never an end of an open one."""
    if periodic:
        by = min(by, (n - 1 - len(run)) // 2)
        return (run[0] - by + np.arange(len(run) + 2 * by)) % n
    return np.arange(max(run[0] - by, 1), min(run[-1] + by, n - 2) + 1)


def _opened_run(textile, i, yarn, run, n, n_points, a, stations, chain, limits) -> np.ndarray | None:
    """The offsets a with one stretch (run) opened, or None where it cannot be (the programme
    above; the move scaled back where the turned sections would reach into another yarn)."""
    pos, up, sec, reach = stations
    tol, gap = limits  # the guard's depth [mm]; the solve's least gap [mm]
    stretch = unwrapped(run, n)
    ext = np.concatenate(([stretch[0] - 1], stretch, [stretch[-1] + 1]))
    q, W = probes(stretch.astype(float), n)  # the stations and points between them
    qpos, _, qup, qside = yarn.frames(q)
    qsec = yarn.section_points(q, n_points)
    qtop, qbottom = extents(qsec)[:2]
    along_up = walls(textile, i, qpos, qup, qside, qsec, sideways=False)
    keep = (1.5 / PROBE_STEPS + margin(qtop + qbottom, gap)) * (qtop + qbottom)  # a probe step and the legs' margin
    room = np.concatenate((np.maximum(along_up[0] - keep - qtop, 0.0), np.maximum(along_up[1] - keep - qbottom, 0.0)))
    A = np.vstack((-W, W))
    m = len(run)
    height = np.ptp(sec[run, :, 1], axis=1)
    kink = second_difference(m) / height[:, None]
    top, bottom = reach[0][run], reach[1][run]
    grid = _grid(yarn, q, n_points, GUARD_STEP * float(min(textile.cell.lx, textile.cell.ly)))
    before = _depths(textile, i, yarn, grid)
    h = float(np.mean(height))
    least = np.min(np.vstack([r[run] for r in reach]), axis=0)
    spacing = np.linalg.norm(np.diff(chain(ext, a), axis=0), axis=1)

    def slack(x):  # >= 0 where no section folds
        offsets = a.copy()
        offsets[run] = x
        points = chain(ext, offsets)
        turn, whole, length = _bends(points, up[run])
        return np.concatenate((BEND_RATIO * length - turn * top, BEND_RATIO * length + turn * bottom,
                               BEND_RATIO * length - whole * least,
                               np.linalg.norm(np.diff(points, axis=0), axis=1) - BEND_SPACING * spacing))

    # in units of the section's height (SLSQP stalls on this programme in mm: its steps are tiny)
    constraints = [{"type": "ineq", "fun": lambda y: slack(h * y) / h},
                   {"type": "ineq", "fun": lambda y: A @ y + room / h, "jac": lambda y: A}]
    result = minimize(lambda y: float(np.sum((kink @ (h * y)) ** 2)), a[run] / h,
                      jac=lambda y: 2 * h * kink.T @ (kink @ (h * y)), method="SLSQP", constraints=constraints,
                      options={"maxiter": 500, "ftol": 1e-12})
    x = h * result.x
    worst = min(np.min(slack(x)), np.min(A @ x + room)) if result.success else -np.inf
    if worst < -1e-9 * h:
        log.debug("bends: stretch %d-%d: no opening (%s, worst %.3g)", run[0], run[-1], result.message, worst)
        return None
    folded = tube(_with_offsets(yarn, n, pos, up, sec, a), textile.resolution).folded
    for scale in BEND_SCALES:  # the sections turn with the path: where they then reach in, the move is scaled back
        out = a.copy()
        out[run] = a[run] + scale * (x - a[run])
        moved = _with_offsets(yarn, n, pos, up, sec, out)
        if np.all(_depths(textile, i, moved, grid) <= np.maximum(before, tol)) and \
                tube(moved, textile.resolution).folded < folded:
            return out
    log.debug("bends: stretch %d-%d: its sections would reach into their neighbours or fold more", run[0], run[-1])
    return None


def open_bends(textile: Textile, yarns: list[int], n_points: int = 32, gap: float = 0.0) -> Textile:
    """The textile with the tight bends of `yarns` (those cut into crowns) opened, never nearer
    than `gap` [mm] (the solve's least gap) to the other yarns where they were not already."""
    new = list(textile.yarns)
    tol = REACH_TOL * min(s.height for y in textile.yarns for s in y.section.sections())
    for i in yarns:
        new[i], moved, left = _opened_yarn(textile, i, n_points, tol, gap)
        if moved:
            log.info("bends: %s's path moved at %d stations where its sections would fold over", new[i].name, moved)
        if left:
            log.info("bends: %s keeps %d tight bend(s) that no move within its room opens", new[i].name, left)
    return replace(textile, yarns=new)
