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
- no section polygon crosses itself.
`assess` returns the metrics before and after with a `verdict`: passed, the failures (each with its
numbers and the worst place), and the tolerances used.
"""

from dataclasses import asdict, dataclass

import numpy as np

from textile_fenicsx.metrics import measure
from textile_fenicsx.sections import Polygon
from textile_fenicsx.stations import stations
from textile_fenicsx.textile import Textile

__all__ = ["Tolerances", "assess", "self_intersecting"]


@dataclass(frozen=True)
class Tolerances:
    """What the corrected model may still have [fractions, -]: overlap volume (of the initial
    overlap), overlap depth (of the thinnest yarn's height), change of a yarn's volume, change of
    a section's area."""

    overlap: float = 0.01
    depth: float = 0.01
    volume: float = 0.01
    section_area: float = 0.01
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
    from textile_fenicsx.legs import steep_runs

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


def _areas(polys: np.ndarray) -> np.ndarray:
    x, y = polys[..., 0], polys[..., 1]
    return 0.5 * np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)


def assess(run, tolerances: Tolerances = Tolerances()) -> dict:
    """Metrics of the run's initial and corrected models and the verdict (collective)."""
    tol = tolerances
    comm = run.comm
    initial, corrected = run.textile, run.corrected
    before = measure(initial, tol.grid, comm)
    out = {"before": before, "after": None, "verdict": {"passed": False, "failures": [], "tolerances": asdict(tol)}}
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
                                               f"{tol.depth * h_min:.3g} mm, {tol.depth:.0%} of the thinnest yarn){where}"})
    v0, v1 = np.array(before["yarn_volume"]["per_yarn"]), np.array(after["yarn_volume"]["per_yarn"])
    change = np.where(v0 > 0, v1 / np.where(v0 > 0, v0, 1) - 1, 0.0)
    out["yarn_volume_change"] = change.tolist()
    # a yarn keeps its sections' areas, so its volume changes with its length (centreline length
    # over its in-plane length: 1 + crimp): what is held is the volume per length. Not held across
    # a free edge (yarn runs in and out of the box) and for a yarn with legs (legs.py: their
    # corners are rebuilt, and the sections' areas are held instead)
    length = (1 + np.array(after["crimp"])) / (1 + np.array(before["crimp"]))
    per_length = np.where(v0 > 0, (1 + change) / length - 1, 0.0)
    out["yarn_volume_per_length_change"] = per_length.tolist()
    held = np.array([initial.cell.periodic and not _has_legs(y) for y in initial.yarns])
    change_held = np.where(held, per_length, 0.0)
    k = int(np.argmax(np.abs(change_held))) if len(change) else 0
    if len(change) and abs(change_held[k]) > tol.volume:
        verdict["failures"].append({"check": "yarn volume", "value": float(change_held[k]), "limit": tol.volume,
                                    "yarn": k, "message": f"{names[k]} (yarn {k}) changed its volume per length by "
                                                          f"{change_held[k]:+.2%} (limit {tol.volume:.0%}; volume "
                                                          f"{change[k]:+.2%}, length {length[k] - 1:+.2%})"})
    spacing = run.settings.correction.station_spacing(run.settings.mesh.seed)
    area_change = []
    for i, (y0, y1) in enumerate(zip(initial.yarns, corrected.yarns)):
        polys = _sections(corrected, i)
        if polys is None:
            area_change.append(0.0)
            continue
        crossed = np.flatnonzero(self_intersecting(polys))
        if len(crossed):
            verdict["failures"].append({"check": "section", "yarn": i, "station": int(crossed[0]),
                                        "message": f"{names[i]} (yarn {i}): {len(crossed)} section polygons cross "
                                                   f"themselves (first at station {int(crossed[0])})"})
        a0 = _areas(y0.section_points(stations(y0, spacing), polys.shape[1]))
        ratio = _areas(polys) / a0 - 1 if len(a0) == len(polys) else np.zeros(1)
        area_change.append(float(ratio[np.argmax(np.abs(ratio))]))
        if abs(area_change[-1]) > tol.section_area:
            verdict["failures"].append({"check": "section area", "yarn": i, "value": area_change[-1],
                                        "limit": tol.section_area,
                                        "message": f"{names[i]} (yarn {i}): a section's area changed by "
                                                   f"{area_change[-1]:+.2%} (limit {tol.section_area:.0%})"})
    out["section_area_change"] = area_change
    verdict["passed"] = not verdict["failures"]
    return out
