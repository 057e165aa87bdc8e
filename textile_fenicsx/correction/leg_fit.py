"""Binder legs fitted into the gap beside them, after the solve (DESIGN.md 7b; issue 27, item 4).

A binder's leg is not a plate (legs.py): the plates move yarns vertically, and a leg thicker than
the gap between the weft columns it passes through, or off its middle, stays in its neighbours.
So after the correction every stretch of a yarn steeper than FIT_SLOPE (a leg and the corners
into its crowns) gets a small lateral problem of its own, with its neighbours held where the solve
put them:

- unknowns per station k: a_k, the path's offset along the section's up vector (in the plane of
  the path's bend: horizontal on a vertical leg), and g_k, the section's squash: the section
  becomes g_k times as thick along up and 1 / g_k times as wide, so its area (its fibres) is kept;
- energy: sum_k (1 - g_k)^2 + KINK_WEIGHT sum_k ((a_{k-1} - 2 a_k + a_{k+1}) / h_k)^2, h_k the
  section's height: a section squashed by x weighs as much as a lateral kink of the path of x / 10
  section heights over one station;
- lateral contact, held at the stations and PROBES_BETWEEN points between each two (a and g
  linear between them): along +-up from the path, the distances d+, d- to the nearest other yarn
  (probed from points across the width); a + g top <= d+ - margin and -a + g bottom <= d- - margin,
  with FIT_MARGIN of the section's height as margin (or the solve's least gap, SolverOptions.min_gap,
  plus a probe step, where that is more: the tet mesh asks for it); across the width, the widened section's edges
  within the room beside them (right / g <= s+ - margin, left / g <= s- - margin, less a side
  probe's step where a wall is seen: a lower bound on g); g >= FIT_LEAST; a = 0 beyond the
  stretch's ends (it joins the unchanged crowns).

A convex quadratic programme per stretch (scipy's SLSQP; where its line search stalls at the
optimum asked to 1e-12, confirmed from there to 1e-10), solved only where a section (thickened by
the margin) reaches into a neighbour; where none exists the stretch is left as it was, with a
warning. The fitted yarn has nodes at the stations, and where two neighbouring stations' squashes
differ by more than SQUASH_RATIO on a straight step, at the probe points between them too, with
the sections the fit held there (the surface joins nodes' sections point by point, and a lone
station squashed hard would hold more fibres between its nodes than its area says).

What it does not do: the neighbours do not move (the weft columns do not move apart in the plane),
and the fit does not feed back into the plates' solve.
"""

import logging
from dataclasses import replace

import numpy as np
from scipy.optimize import minimize

from textile_fenicsx.correction.correct import SECTION_TOL, sparse_sections
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.model.yarn import Yarn

__all__ = ["FIT_SLOPE", "along", "extents", "fit_legs", "margin", "probes", "rebuilt", "runs", "second_difference",
           "side_reach", "squashed", "unwrapped", "walls"]

log = logging.getLogger(__name__)

# stations whose path is steeper than this (|dz| / |dxy|, 30 degrees) belong to a leg's stretch:
# the leg (legs.STEEP, 72 degrees) and the corners where it turns into its crowns
FIT_SLOPE = np.tan(np.radians(30.0))
# the gap kept to a neighbour, in section heights
FIT_MARGIN = 0.03
# the thinnest a section may be squashed to (its width grows to 1 / FIT_LEAST)
FIT_LEAST = 0.4
# probes: distances along +-up per station, and points across the section's width
PROBE_STEPS = 60
PROBE_ACROSS = (-0.7, 0.0, 0.7)
# the weight of the path's lateral kinks against the sections' squash: a squash by x weighs as much
# as a kink of x / 10 section heights over one station. Lighter kinks (1 or 10) let the path swerve
# between the weft columns' edges and fold: on the wide-binder orthogonal weave the overlap left was
# 0.045 mm deep and the binders' swept-back volume doubled (0.74 -> 1.4 %); at 100 and 1000 none is
# left and the folds are the solve's own (0.76 and 0.72 %)
KINK_WEIGHT = 100.0
# the least ratio of two neighbouring stations' squashes joined directly. The surface joins the
# sections of two nodes point by point, and between sections squashed by g and g r (areas kept) the
# joined ones hold up to (1 + r)^2 / (4 r) as much: a lone station squashed to 0.4 between two at
# 0.87 (the binder1.375 weave's legs) gave its binders +1.3 % volume per length. A stretch with
# steeper steps gets nodes at its probe points too, with the sections the fit held there
SQUASH_RATIO = 0.7
# ... where the path is straight: round a bend, nodes closer than the stations sample the fold of
# the sections on its inside, which the stations miss (on the binder of tests/test_leg_fit.py,
# turning 0.54 rad a station, its folded volume went from 0.28 to 0.84 % and 3 % of it was lost)
STRAIGHT_TURN = 0.05
# probe points between two stations (the path is a cubic through them, and bends between them)
PROBES_BETWEEN = 3


def runs(mask: np.ndarray) -> list[np.ndarray]:
    """The maximal runs of consecutive True entries of a cyclic mask (index arrays, in order)."""
    n = len(mask)
    if mask.all() or not mask.any():
        return [np.arange(n)] if mask.all() else []
    start = int(np.argmin(mask))  # a False entry: no run wraps past it
    order = (start + np.arange(n)) % n
    runs, current = [], []
    for k in order:
        if mask[k]:
            current.append(k)
        elif current:
            runs.append(np.array(current))
            current = []
    if current:
        runs.append(np.array(current))
    return runs


def unwrapped(run: np.ndarray, n: int) -> np.ndarray:
    """The stations of a run (in order, it may wrap past n) counted on: n, n + 1, ... after the wrap."""
    return run + n * np.concatenate(([0], np.cumsum(np.diff(run) < 0)))


def second_difference(m: int) -> np.ndarray:
    """The (m, m) matrix of second differences over m stations, zero beyond both ends."""
    return np.diag(np.full(m, -2.0)) + np.diag(np.ones(m - 1), 1) + np.diag(np.ones(m - 1), -1)


def rebuilt(yarn: Yarn, n: int, stations: np.ndarray, polys: np.ndarray, per_node: dict | None = None) -> Yarn:
    """The yarn through its n stations moved to `stations` (n, 3), with these section polygons
    (n, P, 2) at them (a periodic yarn's last node and polygon repeat its first). per_node: its
    ups, angles and tangents where the stations are not its nodes (along())."""
    nodes = yarn.nodes.copy() if per_node is None else np.zeros((n + (1 if yarn.periodic else 0), 3))
    nodes[:n] = stations
    if yarn.periodic:
        nodes[n] = nodes[0] + yarn.period
        polys = np.concatenate((polys, polys[:1]))
    tol = SECTION_TOL * float(np.min(np.ptp(polys[..., 1], axis=1)))
    return replace(yarn, nodes=nodes, section=sparse_sections(nodes, polys, yarn.periodic, tol), **(per_node or {}))


def along(yarn: Yarn, params: np.ndarray) -> tuple[np.ndarray, dict]:
    """Positions on the centreline at the sorted parameters `params`, and the yarn's per-node ups,
    angles and tangents interpolated there linearly, as its frames are between nodes (for nodes at
    params; a periodic yarn's closing node added)."""
    if yarn.periodic:
        params = np.append(params, len(yarn.nodes) - 1.0)
    i = np.minimum(np.floor(params).astype(int), len(yarn.nodes) - 2)
    t = params - i

    def at(v: np.ndarray | None) -> np.ndarray | None:
        return None if v is None else v[i] + (v[i + 1] - v[i]) * (t[:, None] if v.ndim == 2 else t)

    return yarn.centreline(params)[0], {"ups": at(yarn.ups), "angles": at(yarn.angles), "tangents": at(yarn.tangents)}


def margin(height: np.ndarray, gap: float) -> np.ndarray:
    """The gap kept to a neighbour by a section `height` mm thick, in its heights: FIT_MARGIN, or the
    solve's least gap `gap` [mm] and a probe step (the probes see a wall up to a step late)."""
    return np.maximum(FIT_MARGIN, gap / height + 1.5 / PROBE_STEPS)


def side_reach(edge: np.ndarray, height: np.ndarray, gap: float) -> np.ndarray:
    """How far [mm] the probes look sideways from a section's edge `edge` [mm] away from its path:
    as far as a squash to FIT_LEAST widens it, and the margin (margin())."""
    return edge * (1 / FIT_LEAST - 1) + margin(height, gap) * height


def extents(sec: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per section (S, P, 2) in (side, up): how far it reaches up, down, right and left [mm]."""
    return sec[..., 1].max(axis=1), -sec[..., 1].min(axis=1), sec[..., 0].max(axis=1), -sec[..., 0].min(axis=1)


def _reaches(textile: Textile, i: int, pos, up, side, sec, gap: float) -> bool:
    """Does a section (thickened by the margin on each side) reach into another yarn than i?"""
    height = np.ptp(sec[..., 1], axis=1)
    u, v = sec[..., 0], sec[..., 1] * (1 + 2 * margin(height, gap))[:, None]
    points = pos[:, None] + u[..., None] * side[:, None] + v[..., None] * up[:, None]
    inside = textile.inside(points.reshape(-1, 3))
    inside[:, i] = False
    return bool(inside.any())


def _first_hits(textile: Textile, i: int, rays: list) -> list[np.ndarray]:
    """For each bundle of rays (origins (M, P, 3), directions (M, 3), lengths (M,)), per probe
    point m how far [mm] one may go along its direction from its P origins before a point of
    another yarn than i (the least over the origins), up to its length: every point of every
    bundle in one query (a query's cost is mostly per yarn, not per point)."""
    steps = np.linspace(0.0, 1.0, PROBE_STEPS + 1)[1:]
    points = [o[:, :, None] + (steps[None, :, None] * length[:, None, None])[:, None] * d[:, None, None]
              for o, d, length in rays]  # (M, P, R, 3) each
    inside = textile.inside(np.concatenate([p.reshape(-1, 3) for p in points]))
    inside[:, i] = False
    hit: np.ndarray = np.asarray(inside.any(axis=1))
    out, start = [], 0
    for p, (_, _, length) in zip(points, rays):
        h = hit[start:start + p[..., 0].size].reshape(p.shape[:3])
        start += p[..., 0].size
        first = np.where(h.any(axis=2), steps[h.argmax(axis=2)], 1.0)  # (M, P), in lengths
        out.append(first.min(axis=1) * length)
    return out


def walls(textile: Textile, i: int, pos, up, side, sec, sideways: bool = True,
          gap: float = 0.0) -> tuple[np.ndarray, ...]:
    """Per probe point (pos, up, side, its section sec), the room [mm] from the path to the nearest
    other yarn: along +up and -up (from points across the section's width; up to 1.5 section
    heights), and with sideways along +side and -side (from the section's edges, at heights across
    it; up to the width a squash to FIT_LEAST asks, and the margin: `gap`, margin())."""
    top, bottom, right, left = extents(sec)
    height = top + bottom
    across = np.array(PROBE_ACROSS)
    rays = []
    for sign in (1.0, -1.0):
        origins = pos[:, None] + (across[None, :] * 0.5 * (right + left)[:, None])[..., None] * side[:, None]
        rays.append((origins, sign * up, 1.5 * height))
    for sign, edge in ((1.0, right), (-1.0, left)) if sideways else ():
        origins = (pos[:, None] + (sign * edge)[:, None, None] * side[:, None]
                   + (across[None, :] * 0.5 * top[:, None])[..., None] * up[:, None])
        rays.append((origins, sign * side, side_reach(edge, height, gap)))
    hits = _first_hits(textile, i, rays)
    return tuple(hits[:2]) + ((right + hits[2], left + hits[3]) if sideways else ())


def _fit(W: np.ndarray, sec: np.ndarray, room: tuple, station_height,
         gap: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Offsets a and squashes g at the m stations of one stretch (the lateral problem above), held
    at the Q probe points between them (W, (Q, m): each point's weights on the stations; sec: its
    section; room: its room, walls()), or None where no fit exists or the programme fails."""
    m = W.shape[1]
    top, bottom, right, left = extents(sec)
    height = top + bottom
    dp, dm, sp, sm = room
    keep = margin(height, gap) * height
    room_p, room_m = dp - keep, dm - keep
    # the width grows as 1 / g: g no less than the room across the width allows (a wall seen up to a
    # side probe's step late: kept off by that step too; the binder1.375 weave's legs came 0.0077 mm
    # from a stuffer for the 0.0224 kept)
    across = []
    for edge, room_ in ((right, sp), (left, sm)):
        reach = side_reach(edge, height, gap)
        late = np.where(room_ < edge + reach * (1 - 1e-9), reach / PROBE_STEPS, 0.0)
        across.append(edge / np.maximum(room_ - keep - late, 1e-12))
    least = np.maximum(FIT_LEAST, np.maximum(*across))
    if np.any(room_p + room_m < least * (top + bottom)) or np.any(least > 1):
        return None
    D = second_difference(m) * (np.sqrt(KINK_WEIGHT) / station_height[:, None])

    def energy(x):
        return float(np.sum((1 - x[m:]) ** 2) + np.sum((D @ x[:m]) ** 2))

    def gradient(x):
        return np.concatenate((2 * D.T @ (D @ x[:m]), -2 * (1 - x[m:])))

    A = np.vstack((np.hstack((-W, -top[:, None] * W)), np.hstack((W, -bottom[:, None] * W)),
                   np.hstack((np.zeros_like(W), W))))
    b = np.concatenate((room_p, room_m, -least))

    def programme(x0: np.ndarray, ftol: float):
        constraints = {"type": "ineq", "fun": lambda x: A @ x + b, "jac": lambda x: A}
        return minimize(energy, x0, jac=gradient, method="SLSQP", constraints=[constraints],
                        bounds=[(None, None)] * m + [(FIT_LEAST, 1.0)] * m, options={"maxiter": 500, "ftol": ftol})

    result = programme(np.concatenate((np.zeros(m), np.full(m, 1.0))), 1e-12)
    if result.status == 8:  # SLSQP's line search can stall at the optimum asked to 1e-12 (the binder1.375
        result = programme(result.x, 1e-10)  # weave's legs; trust-constr's optima equal): confirmed from there
    if not result.success or np.min(A @ result.x + b) < -1e-9 * np.max(height):
        return None
    return result.x[:m], result.x[m:]


def _steep_steps(g: np.ndarray) -> np.ndarray:
    """Per step between two neighbouring stations of a stretch, is the ratio of their squashes less
    than SQUASH_RATIO."""
    return np.minimum(g[1:] / g[:-1], g[:-1] / g[1:]) < SQUASH_RATIO


def _straight_steps(run: np.ndarray, tan: np.ndarray) -> np.ndarray:
    """Per step between two neighbouring stations of a stretch (run: their indices; tan: every
    station's unit tangent), does the path turn by less than STRAIGHT_TURN over it."""
    return np.sum(tan[run[1:]] * tan[run[:-1]], axis=1) > np.cos(STRAIGHT_TURN)


def squashed(sec: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Sections (S, P, 2) in (side, up) squashed by g (S,): g times as thick, 1 / g times as wide."""
    return np.stack((sec[..., 0] / g[:, None], sec[..., 1] * g[:, None]), axis=-1)


def probes(run: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Parameters of the probe points of a stretch (its stations and PROBES_BETWEEN points
    between each two) and their weights on its stations (linear in the parameter)."""
    m = len(run)
    t = np.arange(PROBES_BETWEEN + 1) / (PROBES_BETWEEN + 1)
    k = np.repeat(np.arange(m - 1), len(t))
    tt = np.tile(t, m - 1)
    s = np.concatenate((run[k] + tt, [run[-1]]))
    W = np.zeros((len(s), m))
    W[np.arange(len(k)), k] = 1 - tt
    W[np.arange(len(k)), k + 1] = tt
    W[-1, -1] = 1.0
    return np.where(s > n, s - n, s), W


def _fitted_yarn(textile: Textile, i: int, n_points: int, gap: float) -> tuple[Yarn, int, float]:
    """Yarn i with its legs' stretches fitted (or as it was); stations changed and the least g."""
    yarn = textile.yarns[i]
    n = len(yarn.nodes) - (1 if yarn.periodic else 0)  # a periodic yarn's last node repeats its first
    s = np.arange(n, dtype=float)
    pos, tan, up, side = yarn.frames(s)
    steep = np.abs(tan[:, 2]) > FIT_SLOPE * np.linalg.norm(tan[:, :2], axis=1)
    if not steep.any() or steep.all():
        return yarn, 0, 1.0
    sec = yarn.section_points(s, n_points)
    a, g = np.zeros(n), np.ones(n)
    between = []  # (params, nodes, sections) at the probe points of stretches squashed in steep steps
    for run in runs(steep):
        q, W = probes(unwrapped(run, n).astype(float), n)
        qpos, _, qup, qside = yarn.frames(q)
        qsec = yarn.section_points(q, n_points)
        if not _reaches(textile, i, qpos, qup, qside, qsec, gap):
            continue
        top, bottom, _, _ = extents(qsec)
        height = top + bottom
        room = walls(textile, i, qpos, qup, qside, qsec, gap=gap)
        keep = margin(height, gap) * height
        reach = (top + keep > room[0]) | (bottom + keep > room[1])
        if not reach.any():
            continue
        station_height = np.ptp(sec[run, :, 1], axis=1)
        fit = _fit(W, qsec, room, station_height, gap)
        c = int(np.argmax(reach))
        if fit is None and gap > 0:  # too narrow for the solve's gap beside it: the fit's own margin
            fit = _fit(W, qsec, room, station_height, 0.0)
            if fit is not None:
                log.warning("legs: %s's leg at (%.3f, %.3f, %.3f) mm is fitted into its gap with less than the "
                            "solve's least gap (%.4f mm) beside it: a tet mesh with that gap will refuse it",
                            yarn.name, *qpos[c], gap)
        if fit is None:
            log.warning("legs: %s's leg at (%.3f, %.3f, %.3f) mm cannot be fitted into the gap beside it (%.4f mm "
                        "for a section %.4f mm thick, %.4f mm across its width for %.4f): left as it is",
                        yarn.name, *qpos[c], room[0][c] + room[1][c], height[c], room[2][c] + room[3][c],
                        np.ptp(qsec[c, :, 0]))
            continue
        a[run], g[run] = fit
        steep_steps = _steep_steps(fit[1]) & _straight_steps(run, tan)
        if steep_steps.any():  # the surface through the probe points the fit held between them
            inner = (W.max(axis=1) < 1.0) & (W[:, :-1] > 0).any(axis=1)  # between stations k and k + 1 ...
            inner[inner] = steep_steps[np.argmax(W[inner, :-1] > 0, axis=1)]  # ... where the step is steep
            between.append((q[inner], squashed(qsec[inner], W[inner] @ fit[1])))
    changed = int(np.sum((np.abs(a) > 0) | (g < 1)))
    if not changed:
        return yarn, 0, 1.0
    polys = squashed(sec, g)
    fitted = rebuilt(yarn, n, pos + a[:, None] * up, polys)
    if between:  # nodes added on the fitted path, with the sections the fit held there
        params = np.concatenate([s] + [b[0] for b in between])
        order = np.argsort(params, kind="stable")
        nodes, per_node = along(fitted, params[order])
        polys = np.concatenate([polys] + [b[1] for b in between])[order]
        fitted = rebuilt(fitted, len(order), nodes[:len(order)], polys, per_node)
    return fitted, changed, float(g.min())


def fit_legs(textile: Textile, yarns: list[int], n_points: int = 32, gap: float = 0.0) -> Textile:
    """The corrected textile with the legs of `yarns` (those cut into crowns) fitted into their gaps,
    keeping at least `gap` [mm] (the solve's least gap) to their neighbours."""
    new = list(textile.yarns)
    for i in yarns:
        new[i], changed, least = _fitted_yarn(textile, i, n_points, gap)
        if changed:
            log.info("legs: %s fitted into the gaps beside its legs at %d stations (sections squashed to %.3f of "
                     "their thickness at most, areas kept)", textile.yarns[i].name, changed, least)
    return replace(textile, yarns=new)
