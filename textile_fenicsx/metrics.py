"""Metrics of a textile model (DESIGN.md section 8), measured on the model, not on a FE mesh.

Columns on an n x n cell-centred grid of the unit cell give every yarn interval over each point;
clipped to the cell's z range when it has one. Then:
- yarn volume: sum over points of interval lengths x the area a point represents;
- interpenetration: the length of z inside two or more yarns (volume: its integral; max depth: its
  maximum), and per yarn pair the overlap max(0, min(top_a, top_b) - max(bot_a, bot_b));
- thickness: highest top - lowest bottom; crimp: centreline length / in-plane length - 1;
- fibre volume fraction: each yarn's intra-yarn fraction (its fibres' cross-section over its mean
  section area; fibres.DEFAULT_YARN_VF, with a warning, for a yarn without fibre data), and the cell's:
  sum of yarn volume x intra-yarn fraction over the cell's volume (cell area x thickness).
"""

import logging
from typing import Any

import numpy as np

from textile_fenicsx.fibres import DEFAULT_YARN_VF
from textile_fenicsx.limits import MAX_GRID, check_count
from textile_fenicsx.textile import Columns, Textile

log = logging.getLogger(__name__)
# models already warned of their missing fibre data (once per model and process: a run measures the
# input and its corrected model, and meshes it)
_WARNED: set[str] = set()


def _clipped(textile: Textile, col: Columns) -> tuple[np.ndarray, np.ndarray]:
    bot, top = col.bottom, col.top
    if textile.cell.z_range is not None:
        lo, hi = textile.cell.z_range
        bot, top = np.clip(bot, lo, hi), np.clip(top, lo, hi)
    return bot, top


def coverage_depth(n_points: int, point: np.ndarray, bottom: np.ndarray, top: np.ndarray,
                   at_least: int = 2) -> np.ndarray:
    """Per point, the length of z covered by at least `at_least` of the given intervals."""
    z = np.concatenate((bottom, top))
    p = np.concatenate((point, point))
    step = np.concatenate((np.ones_like(bottom), -np.ones_like(top)))
    order = np.lexsort((-step, z, p))  # at equal z, openings before closings
    z, p, step = z[order], p[order], step[order]
    count = np.cumsum(step)
    gap = np.diff(z, append=z[-1:] if len(z) else z)
    same = np.r_[p[1:] == p[:-1], False]
    covered = np.where(same & (count >= at_least), gap, 0.0)
    return np.bincount(p, weights=covered, minlength=n_points)


def crimp(textile: Textile) -> list[float]:
    """Per yarn: centreline length over its in-plane (xy-projected) length, minus 1."""
    out = []
    for y in textile.yarns:
        s, cum = y.length_table()
        pos, _ = y.centreline(s)
        flat = np.sum(np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1))
        out.append(float(cum[-1] / flat - 1) if flat > 0 else float("inf"))
    return out


def measure(textile: Textile, n: int = 200, comm=None) -> dict:
    """The metrics of the textile as a JSON-ready dict (mm, mm^3), sampled on an n x n grid.

    With an MPI communicator the grid points are split over its ranks and the sums reduced, so
    every rank returns the same answer as a serial call.
    """
    n = check_count("metrics grid (rays per cell side)", n, 1, MAX_GRID)
    xy, dA = textile.cell.grid(n)
    if comm is not None and comm.size > 1:
        xy = np.array_split(xy, comm.size)[comm.rank]
    col = textile.columns(xy)
    textile.forget_surfaces()  # every ray is cast: the triangles are not needed any more
    bot, top = _clipped(textile, col)
    n_yarns = len(textile.yarns)
    per_yarn = np.bincount(col.yarn, weights=top - bot, minlength=n_yarns) * dA
    depth = coverage_depth(len(xy), col.point, bot, top)

    pairs: dict[tuple[int, int], tuple] = {}  # (a, b) -> (volume, max depth, where)
    # rows are sorted by point: pair every row with the later rows of the same point
    for shift in range(1, max(2, int(np.bincount(col.point).max()) if len(col.point) else 1)):
        a, b = np.arange(len(col.point) - shift), np.arange(shift, len(col.point))
        same = (col.point[a] == col.point[b]) & (col.yarn[a] != col.yarn[b])
        a, b = a[same], b[same]
        ov = np.minimum(top[a], top[b]) - np.maximum(bot[a], bot[b])
        pos = ov > 0
        ya, yb, o, pt = col.yarn[a][pos], col.yarn[b][pos], ov[pos], col.point[a][pos]
        code = np.minimum(ya, yb).astype(np.int64) * n_yarns + np.maximum(ya, yb)
        keys, inverse = np.unique(code, return_inverse=True)
        volume = np.bincount(inverse, weights=o, minlength=len(keys)) * dA
        order = np.lexsort((o, inverse))  # per key, deepest last
        last = order[np.r_[np.flatnonzero(np.diff(inverse[order])), len(order) - 1]] if len(order) else order
        for key, v, k in zip(keys.tolist(), volume, last):
            pair = (key // n_yarns, key % n_yarns)
            v0, d0, at0 = pairs.get(pair, (0.0, 0.0, None))
            pairs[pair] = (v0 + float(v), max(d0, float(o[k])),
                           at0 if d0 >= o[k] else [float(xy[pt[k], 0]), float(xy[pt[k], 1])])

    deepest = int(np.argmax(depth)) if len(depth) else 0
    local: dict[str, Any] = {"volume": float(depth.sum() * dA), "max_depth": float(depth.max()) if len(depth) else 0.0,
             "at": xy[deepest].tolist() if len(depth) else None,
             "z_lo": float(bot.min()) if len(bot) else np.inf, "z_hi": float(top.max()) if len(top) else -np.inf,
             "odd": col.odd}
    if comm is not None and comm.size > 1:
        from mpi4py import MPI

        per_yarn = comm.allreduce(per_yarn, op=MPI.SUM)
        merged: dict[tuple[int, int], tuple] = {}
        for part in comm.allgather(pairs):
            for k, (v, d, at) in part.items():
                v0, d0, at0 = merged.get(k, (0.0, 0.0, None))
                merged[k] = (v0 + v, max(d0, d), at0 if d0 >= d else at)
        pairs = merged
        deepest = max(comm.allgather((local["max_depth"], local["at"])), key=lambda p: p[0])
        local = {"volume": comm.allreduce(local["volume"], op=MPI.SUM),
                 "max_depth": deepest[0], "at": deepest[1],
                 "z_lo": comm.allreduce(local["z_lo"], op=MPI.MIN),
                 "z_hi": comm.allreduce(local["z_hi"], op=MPI.MAX),
                 "odd": comm.allreduce(local["odd"], op=MPI.SUM)}
    thickness = local["z_hi"] - local["z_lo"] if np.isfinite(local["z_hi"]) else 0.0
    yarn_vf, vf_source = yarn_fibre_fractions(textile)
    return {
        "yarn_volume": {"total": float(per_yarn.sum()), "per_yarn": per_yarn.tolist()},
        "interpenetration": {
            "volume": local["volume"],
            "max_depth": local["max_depth"],
            "at": local["at"],
            "pairs": [{"yarns": list(k), "volume": float(v), "max_depth": float(d), "at": at}
                      for k, (v, d, at) in sorted(pairs.items())],
        },
        "thickness": float(thickness),
        "crimp": crimp(textile),
        "vf": fibre_volume_fraction(yarn_vf, per_yarn, textile.cell.area * float(thickness)),
        "yarn_vf": yarn_vf,
        "fibre_data": vf_source,
        "sampling": {"grid": [n, n], "cell_area_per_sample": dA, "odd_parity_columns": local["odd"]},
    }


# Points per section when measuring section areas: a 64-point polygon holds 0.16 % less than its
# ellipse, a 1024-point one 6e-4 %.
AREA_POINTS = 1024


def mean_section_area(yarn, resolution) -> float:
    """The yarn's section area averaged along its length [mm^2] (stations of its surface, weighted
    by the arc length each represents): its volume per unit length."""
    s = yarn.stations(resolution.spacing, resolution.per_segment)
    pts = yarn.section_points(s, max(resolution.section_points, AREA_POINTS))
    x, y = pts[..., 0], pts[..., 1]
    area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))
    pos, _ = yarn.centreline(s)
    ds = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    return float(np.sum(0.5 * (area[1:] + area[:-1]) * ds) / np.sum(ds))


def yarn_fibre_fractions(textile: Textile) -> tuple[list[float], str]:
    """Each yarn's intra-yarn fibre volume fraction (its fibres' cross-section over its mean section
    area) and where the fibre data came from: "model", or the stated default
    (fibres.DEFAULT_YARN_VF, with a warning) for yarns without fibre data."""
    fractions, missing = [], []
    for y in textile.yarns:
        area = y.fibres.fibre_area() if y.fibres is not None else None
        if area is None:
            missing.append(y.name)
            fractions.append(DEFAULT_YARN_VF)
        else:
            fractions.append(area / mean_section_area(y, textile.resolution))
    if missing and textile.name.removesuffix("_corrected") not in _WARNED:
        _WARNED.add(textile.name.removesuffix("_corrected"))
        log.warning("%s: no fibre data (fibres per yarn and diameter, fibre area, or linear density and fibre "
                    "density) for %s; their fibre volume fraction is taken as %g", textile.name,
                    ", ".join(missing[:3]) + (f" and {len(missing) - 3} more" if len(missing) > 3 else ""),
                    DEFAULT_YARN_VF)
    source = "model" if not missing else "default" if len(missing) == len(textile.yarns) else "model and default"
    return fractions, source


def fibre_volume_fraction(yarn_vf: list[float], yarn_volumes: np.ndarray, volume: float) -> float | None:
    """Fibre volume over the cell's volume (cell area x thickness) [-]; None for no volume."""
    if volume <= 0:
        return None
    return float(np.dot(yarn_vf, yarn_volumes) / volume)
