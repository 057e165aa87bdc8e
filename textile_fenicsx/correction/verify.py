"""The check after every run, on the corrected model itself (not on the FE solution).

The corrected textile is measured as any model is (metrics.measure: vertical rays through its
yarn surfaces) and compared with the initial one. A run passes when
- its yarns overlap by at most `overlap` of the initial overlap volume (or of the thinnest yarn's
  height x the cell area x 1e-3 when the initial model had almost none), and nowhere deeper than
  `depth` x the thinnest yarn's height;
- every yarn keeps its volume per length (its volume over 1 + crimp) within `volume` (a
  fraction), and every section's area within `section_area` of the initial section's at the same
  station (the tension shortens crimped yarns: a binder loses length, and with it volume in the
  cell, at constant area); the volume is not held across a free edge (yarns run in and out of the
  box) nor for a yarn with legs (legs.py), whose sections' areas are;
- every yarn, legs and free edges included, keeps the volume per length its own surface encloses
  (tube(): the divergence theorem over its tube, over the length of its sections' centroids'
  line, the path where they are centred on it) within `volume`,
  and folds over itself (sections swept backwards on the inside of a bend tighter than they are
  thick, a volume the sections' areas count and space does not) by at most `fold` of its volume
  more than in the input;
- no section polygon crosses itself.
Where the fabric was pressed and its yarns flattened (compaction.py), a yarn's volume per length is
held to the change its plate's volume made, int (t + dt) / int t (the fibres are kept; the volume
they fill is the law's), a section's area is not compared station by station (the sections flatten
by the pressure where they are, which the input's sections do not say), no yarn may hold more
fibre than the maximum packing, and a compaction that stopped short of its target fails.
`assess` returns the metrics before and after with a `verdict`: passed, the failures (each with its
numbers and the worst place), and the tolerances used.
"""

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from textile_fenicsx.correction.stations import budgets, stations
from textile_fenicsx.model.metrics import measure
from textile_fenicsx.model.sections import Polygon, polygon_centroids
from textile_fenicsx.model.textile import Textile

__all__ = ["Tolerances", "assess", "self_intersecting"]


@dataclass(frozen=True)
class Tolerances:
    """What the corrected model may still have [fractions, -]: overlap volume (of the initial
    overlap), overlap depth (of the thinnest yarn's height), change of a yarn's volume per length,
    change of a section's area, a yarn's volume swept backwards where it folds over (of its
    volume, beyond the input's own)."""

    overlap: float = 0.01
    depth: float = 0.01
    volume: float = 0.01
    section_area: float = 0.01
    fold: float = 0.001
    grid: int = 200


def self_intersecting(polygons: np.ndarray) -> np.ndarray:
    """For polygons (S, n, 2), whether each crosses itself (two non-adjacent edges intersect).
    A strictly convex polygon (every turn the same way, one turn in all) cannot: only the others
    have their pairs of edges tested."""
    out = np.zeros(len(polygons), bool)
    rest = np.flatnonzero(~_strictly_convex(np.asarray(polygons, float)))
    if len(rest):
        out[rest] = _edges_cross(np.asarray(polygons, float)[rest])
    return out


def _strictly_convex(p: np.ndarray) -> np.ndarray:
    """(S,) whether each polygon (S, n, 2) turns the same way at every vertex (no straight or
    doubled vertex) and by one full turn in all: a simple convex polygon."""
    e = np.roll(p, -1, axis=1) - p
    f = np.roll(e, -1, axis=1)
    cross = e[..., 0] * f[..., 1] - e[..., 1] * f[..., 0]
    turning = np.arctan2(cross, np.sum(e * f, axis=-1)).sum(axis=1)
    one_way = np.all(cross > 0, axis=1) | np.all(cross < 0, axis=1)
    return one_way & (np.abs(np.abs(turning) - 2 * np.pi) < 1e-6)


def _edges_cross(p: np.ndarray) -> np.ndarray:
    """(S,) whether two non-adjacent edges of each polygon (S, n, 2) cross (every pair tested)."""
    a, b = p, np.roll(p, -1, axis=1)  # edge k: a[k] -> b[k]
    n = p.shape[1]
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))  # the first and last edges share a vertex
    i, j = i[keep], j[keep]
    out = np.zeros(len(p), bool)
    for start in range(0, len(p), 256):
        A, B = a[start:start + 256], b[start:start + 256]

        def orient(P, Q, R):
            return np.sign((Q[..., 0] - P[..., 0]) * (R[..., 1] - P[..., 1])
                           - (Q[..., 1] - P[..., 1]) * (R[..., 0] - P[..., 0]))

        d1 = orient(A[:, i], B[:, i], A[:, j])
        d2 = orient(A[:, i], B[:, i], B[:, j])
        d3 = orient(A[:, j], B[:, j], A[:, i])
        d4 = orient(A[:, j], B[:, j], B[:, i])
        out[start:start + 256] = np.any((d1 * d2 < 0) & (d3 * d4 < 0), axis=1)
    return out


def _sections(textile: Textile, i: int) -> np.ndarray | None:
    """The corrected yarn's polygons (S, n, 2) at its stations (its master nodes, blended where
    the file keeps fewer), or None when it has no polygon sections."""
    yarn = textile.yarns[i]
    sections = yarn.section.sections()
    if not all(isinstance(s, Polygon) for s in sections) or len({len(s.vertices) for s in sections}) != 1:
        return None
    return yarn.section_points(np.arange(len(yarn.nodes), dtype=float), len(sections[0].vertices))


def _has_legs(yarn) -> bool:
    from textile_fenicsx.correction.legs import steep_runs

    return bool(steep_runs(yarn, 0.05))


def _leg_hint(initial: Textile, pen0: dict, worst: dict | None) -> str:
    """Why an overlap at a yarn's leg stays: the plates move yarns vertically only, and a leg (a
    steep stretch, rebuilt from its crowns' ends) that overlaps its neighbours sideways in the
    input keeps doing so (TexGen's orthogonal weave with a binder thicker than the gap between
    the weft columns). "" unless the pair has a yarn with legs and overlapped before (at least a
    quarter as deep)."""
    if worst is None:
        return ""
    legs = [k for k in worst["yarns"] if _has_legs(initial.yarns[k])]
    same = [p for p in pen0["pairs"] if sorted(p["yarns"]) == sorted(worst["yarns"])]
    if not legs or not same or same[0]["max_depth"] < 0.25 * worst["max_depth"]:
        return ""
    return (f" (they overlapped {same[0]['max_depth']:.3g} mm deep in the input already, at the steep leg of "
            f"{initial.yarns[legs[0]].name}: the plates move yarns vertically only, and a leg thicker than the "
            "gap it passes through, e.g. a binder between weft columns, stays in its neighbours; give it room in "
            "the model)")


@dataclass(frozen=True)
class Tube:
    """A yarn's surface over its master nodes as the metrics see it (its resolution's stations and
    section points), measured: volume [mm^3] enclosed (the divergence theorem, the end sections
    closing it), length [mm] of the line through its sections' centroids at the stations (the
    fibres' mean line; the path's own where the sections are centred on it), folded [mm^3]: the volume its
    sections sweep backwards, at [mm] the path point of the worst fold (None for none); s: the
    parameters along the path where it was measured and back [mm^3]: the volume swept backwards
    between each two (bend_fit.py opens the bends where it is)."""

    volume: float
    length: float
    folded: float
    at: tuple | None
    s: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    back: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    @property
    def per_length(self) -> float:
        return self.volume / self.length


def tube(yarn, resolution) -> Tube:
    """The yarn's tube measured (Tube). The sweep of a section along a path folds over where the
    path turns tighter than the section is thick: on the inside of the bend the next section lies
    behind the last, and that volume is counted twice by its sections' areas and once in space.
    Each point of the section must advance along the path from one station to the next (the mean
    of their tangents); where one goes back, the wedge of section it bounds is folded."""
    verts, s = yarn.tube(resolution.spacing, resolution.section_points, resolution.per_segment)
    pos, tan, up, side = yarn.frames(s)
    a, b = verts[:-1], verts[1:]
    a1, b1 = np.roll(a, -1, axis=1), np.roll(b, -1, axis=1)

    def six(p, q, r):  # 6 x signed volumes of the tetrahedra (0, p, q, r), summed
        return float(np.sum(p * np.cross(q, r)))

    def fan(ring):  # 6 x the signed volume of the cone from the origin over an end section
        c = np.broadcast_to(ring.mean(axis=0), ring.shape)
        return six(c, ring, np.roll(ring, -1, axis=0))

    volume = abs(six(a, b, b1) + six(a, b1, a1) - fan(verts[-1]) + fan(verts[0])) / 6
    bisector = tan[1:] + tan[:-1]
    bisector /= np.maximum(np.linalg.norm(bisector, axis=1, keepdims=True), 1e-300)
    # each wedge of section (the path point and two neighbouring points) advances by the path's
    # advance at its apex and by its points' at its edge, linearly between (exact on an arc)
    apex = np.einsum("mj,mj->m", pos[1:] - pos[:-1], bisector)[:, None]
    edge = np.einsum("mkj,mj->mk", b - a, bisector)
    edge = 0.5 * (edge + np.roll(edge, -1, axis=1))
    wedge = 0.25 * (np.linalg.norm(np.cross(a - pos[:-1, None], a1 - pos[:-1, None]), axis=2)
                    + np.linalg.norm(np.cross(b - pos[1:, None], b1 - pos[1:, None]), axis=2))
    back = (wedge * _backwards(np.broadcast_to(apex, edge.shape), edge)).sum(axis=1)
    m = int(np.argmax(back))
    # per length of the centroids' line: by Pappus a swept section encloses its area times the
    # distance its centroid travels, so where a model's sections sit off its path (TexGen's refined
    # Hybrid sections, flat at the path) a bending path holds A (1 - k c) per length of itself and
    # A per length of the centroids; the correction puts the path on the centroids (DESIGN.md 7)
    c = polygon_centroids(yarn.section_points(s, resolution.section_points))
    length = float(np.sum(np.linalg.norm(np.diff(pos + c[:, :1] * side + c[:, 1:] * up, axis=0), axis=1)))
    return Tube(volume, length, float(back.sum()), tuple(map(float, pos[m])) if back[m] > 0 else None, s, back)


def _backwards(apex: np.ndarray, edge: np.ndarray) -> np.ndarray:
    """The mean over a triangle of max(0, -f), f linear from `apex` at one vertex to `edge` along
    the opposite side (elementwise)."""
    d = edge - apex
    whole = -(apex + 2 * edge) / 3  # f <= 0 everywhere: the mean of -f
    r0 = np.where(apex > 0, apex / np.where(apex - edge > 0, apex - edge, 1.0), 0.0)  # where f = 0
    part = -(apex + 2 * d / 3) + apex * r0**2 + 2 * d * r0**3 / 3  # 2 int_r0^1 -(apex + d r) r dr
    return np.where(edge >= 0, 0.0, np.where(apex <= 0, whole, part))


def _areas(polys: np.ndarray) -> np.ndarray:
    x, y = polys[..., 0], polys[..., 1]
    return 0.5 * np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)


def _compaction_checks(run, after: dict, out: dict, verdict: dict) -> None:
    """A compaction that stopped short of its target, and yarns packed beyond the law's maximum."""
    curve = run.compaction
    if curve.reason is not None:
        verdict["failures"].append({"check": "compaction", "message": f"the compaction stopped short: {curve.reason}"})
    phi_max = run.settings.compaction.phi_max
    densest = max(after["yarn_vf"], default=0.0)
    if densest > phi_max:
        verdict["failures"].append({"check": "packing", "value": densest, "limit": phi_max,
                                    "message": f"a corrected yarn holds a fibre fraction of {densest:.3f}, beyond the "
                                               f"maximum packing {phi_max:.4g}"})


def _surface_checks(initial: Textile, corrected: Textile, tol: Tolerances, out: dict, verdict: dict,
                    expected: np.ndarray | None = None) -> None:
    """Every yarn's volume per length from its own surface, and its folds (tube()): the volume
    per length of the rays (above) counts a yarn's volume in the cell, which a fold-over hides
    (TexGen's orthogonal binders at seed 0.5 held 3.8 % less per length with every section's area
    kept) and which is not held for legs or across free edges; this one is held for every yarn."""
    names = [y.name for y in initial.yarns]
    tubes = [(tube(y0, initial.resolution), tube(y1, corrected.resolution))
             for y0, y1 in zip(initial.yarns, corrected.yarns)]
    expected = np.ones(len(tubes)) if expected is None else expected  # a pressed yarn's plate's change
    per_length = [t1.per_length / t0.per_length / e - 1 for (t0, t1), e in zip(tubes, expected)]
    folded = [max(0.0, t1.folded / t1.volume - t0.folded / t0.volume) for t0, t1 in tubes]
    out["yarn_surface_volume_per_length_change"] = per_length
    out["yarn_folded_fraction"] = [t1.folded / t1.volume for _, t1 in tubes]
    k = int(np.argmax(np.abs(per_length)))
    if abs(per_length[k]) > tol.volume:
        verdict["failures"].append({"check": "yarn surface volume", "value": per_length[k], "limit": tol.volume,
                                    "yarn": k, "message": f"{names[k]} (yarn {k}) changed the volume per length its "
                                                          f"surface encloses by {per_length[k]:+.2%} (limit "
                                                          f"{tol.volume:.0%})"})
    k = int(np.argmax(folded))
    if folded[k] > tol.fold:
        at = tubes[k][1].at
        assert at is not None
        verdict["failures"].append({"check": "fold", "value": folded[k], "limit": tol.fold, "yarn": k, "at": at,
                                    "message": f"{names[k]} (yarn {k}) folds over itself: {folded[k]:.2%} of its "
                                               f"volume is swept backwards (limit {tol.fold:.1%}), most near "
                                               f"({at[0]:.3f}, {at[1]:.3f}, {at[2]:.3f}) mm, where its path turns "
                                               "tighter than its section is thick and the sections overlap on the "
                                               "inside of the bend; its volume in space is less than its sections' "
                                               "areas say"})


def assess(run, tolerances: Tolerances = Tolerances()) -> dict:
    """Metrics of the run's initial and corrected models and the verdict (collective)."""
    tol = tolerances
    comm = run.comm
    initial, corrected = run.textile, run.corrected
    before = measure(initial, tol.grid, comm)
    out: dict[str, Any] = {"before": before, "after": None,
                           "verdict": {"passed": False, "failures": [], "tolerances": asdict(tol)}}
    verdict = out["verdict"]
    if corrected is None:
        verdict["failures"].append({"check": "solve", "message": run.solution.reason})
        return out
    after = measure(corrected, tol.grid, comm)
    out["after"] = after
    names = [y.name for y in initial.yarns]
    h_min = min(s.height for y in initial.yarns for s in y.section.sections())
    pen0, pen = before["interpenetration"], after["interpenetration"]
    allowed = tol.overlap * max(pen0["volume"], 1e-3 * h_min * initial.cell.area)
    worst = max(pen["pairs"], key=lambda p: p["max_depth"], default=None)
    where = (f"; deepest between {names[worst['yarns'][0]]} and {names[worst['yarns'][1]]} at "
             f"({worst['at'][0]:.3f}, {worst['at'][1]:.3f}) mm" if worst else "") + _leg_hint(initial, pen0, worst)
    if pen["volume"] > allowed:
        verdict["failures"].append({"check": "overlap volume", "value": pen["volume"], "limit": allowed,
                                    "message": f"the corrected yarns overlap by {pen['volume']:.4g} mm^3 (before "
                                               f"{pen0['volume']:.4g} mm^3; limit {allowed:.3g}){where}"})
    if pen["max_depth"] > tol.depth * h_min:
        verdict["failures"].append({"check": "overlap depth", "value": pen["max_depth"], "limit": tol.depth * h_min,
                                    "at": worst["at"] if worst else None,
                                    "message": f"the corrected yarns overlap {pen['max_depth']:.4g} mm deep (limit "
                                               f"{tol.depth * h_min:.3g} mm, {tol.depth:.0%} of the thinnest yarn)"
                                               f"{where}"})
    v0, v1 = np.array(before["yarn_volume"]["per_yarn"]), np.array(after["yarn_volume"]["per_yarn"])
    change = np.where(v0 > 0, v1 / np.where(v0 > 0, v0, 1) - 1, 0.0)
    out["yarn_volume_change"] = change.tolist()
    # a yarn keeps its sections' areas, so its volume changes with its length (centreline length
    # over its in-plane length: 1 + crimp): what is held is the volume per length. Not held across
    # a free edge (yarn runs in and out of the box) and for a yarn with legs (legs.py: their
    # corners are rebuilt, and the sections' areas are held instead)
    length = (1 + np.array(after["crimp"])) / (1 + np.array(before["crimp"]))
    per_length = np.where(v0 > 0, (1 + change) / length - 1, 0.0)
    pressed = run.volume_ratio is not None  # yarns that flattened: their plates' volume changed so
    expected = np.asarray(run.volume_ratio) if pressed else np.ones(len(v0))
    if pressed:
        out["yarn_volume_expected_change"] = (expected - 1).tolist()
        per_length = np.where(v0 > 0, (1 + per_length) / expected - 1, 0.0)
    out["yarn_volume_per_length_change"] = per_length.tolist()
    held = np.array([initial.cell.periodic and not _has_legs(y) for y in initial.yarns])
    change_held = np.where(held, per_length, 0.0)
    k = int(np.argmax(np.abs(change_held))) if len(change) else 0
    if len(change) and abs(change_held[k]) > tol.volume:
        verdict["failures"].append({"check": "yarn volume", "value": float(change_held[k]), "limit": tol.volume,
                                    "yarn": k, "message": f"{names[k]} (yarn {k}) changed its volume per length by "
                                                          f"{change_held[k]:+.2%} (limit {tol.volume:.0%}; volume "
                                                          f"{change[k]:+.2%}, length {length[k] - 1:+.2%})"})
    _surface_checks(initial, corrected, tol, out, verdict, expected)
    if run.compaction is not None:
        _compaction_checks(run, after, out, verdict)
    spacing = run.settings.correction.station_spacing(run.settings.mesh.seed)
    most = budgets(initial.yarns, spacing, run.settings.correction.section_points)
    area_change = []
    for i, (y0, _) in enumerate(zip(initial.yarns, corrected.yarns)):
        polys = _sections(corrected, i)
        if polys is None:
            area_change.append(0.0)
            continue
        crossed = np.flatnonzero(self_intersecting(polys))
        if len(crossed):
            verdict["failures"].append({"check": "section", "yarn": i, "station": int(crossed[0]),
                                        "message": f"{names[i]} (yarn {i}): {len(crossed)} section polygons cross "
                                                   f"themselves (first at station {int(crossed[0])})"})
        a0 = _areas(y0.section_points(stations(y0, spacing, most[i]), polys.shape[1]))
        ratio = _areas(polys) / a0 - 1 if len(a0) == len(polys) and not pressed else np.zeros(1)
        area_change.append(float(ratio[np.argmax(np.abs(ratio))]))
        if abs(area_change[-1]) > tol.section_area:
            verdict["failures"].append({"check": "section area", "yarn": i, "value": area_change[-1],
                                        "limit": tol.section_area,
                                        "message": f"{names[i]} (yarn {i}): a section's area changed by "
                                                   f"{area_change[-1]:+.2%} (limit {tol.section_area:.0%})"})
    out["section_area_change"] = area_change
    verdict["passed"] = not verdict["failures"]
    return out
