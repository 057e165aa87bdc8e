"""Metrics of a textile model (DESIGN.md section 8), measured on the model, not on a FE mesh.

Columns on an n x n cell-centred grid of the unit cell give every yarn interval over each point;
clipped to the cell's z range when it has one. Then:
- yarn volume: sum over points of interval lengths x the area a point represents;
- interpenetration: the length of z inside two or more yarns (volume: its integral over the grid;
  max depth: its maximum over the plane), and per yarn pair the overlap max(0, min(top_a, top_b) -
  max(bot_a, bot_b)) (volume and maximum). A maximum is a point's, and the grid's columns sample it:
  where the overlap is a narrow ridge, as where a steep binder leg cuts a weft's edge (TexGen's
  orthogonal weave: 0.056 mm wide at half its height, the grid's spacing), the nearest column sees
  a fraction of it (0.0248 of 0.0301 mm). So each maximum is then sought around the deepest columns
  on ever finer columns (`_deepest`), down to 1/64 of the grid's spacing;
- thickness: highest top - lowest bottom; crimp: centreline length / in-plane length - 1;
- fibre volume fraction: each yarn's intra-yarn fraction (its fibres' cross-section over its mean
  section area; fibres.DEFAULT_YARN_VF, with a warning, for a yarn without fibre data), and the cell's:
  sum of yarn volume x intra-yarn fraction over the cell's volume (cell area x thickness).
"""

import logging
from dataclasses import replace
from typing import Any

import numpy as np

from textile_fenicsx.common.limits import MAX_GRID, check_count
from textile_fenicsx.model.fibres import DEFAULT_YARN_VF, Fibres, check_yarn_vf
from textile_fenicsx.model.queries import columns
from textile_fenicsx.model.textile import Columns, Textile

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
    bot, top = _clipped(textile, col)
    n_yarns = len(textile.yarns)
    per_yarn = np.bincount(col.yarn, weights=top - bot, minlength=n_yarns) * dA
    depth = coverage_depth(len(xy), col.point, bot, top)
    pairs = {k: (v * dA, d, at) for k, (v, d, at) in _pair_overlaps(col, bot, top, xy, n_yarns).items()}

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
    found = _deepest(textile, n, depth, xy, pairs, local, comm)
    textile.forget_surfaces()  # every ray is cast: the triangles are not needed any more
    local["max_depth"], local["at"], pairs = found
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
        "areal": _areal(textile.cell, yarn_vf, per_yarn),
        "yarn_vf": yarn_vf,
        "fibre_data": vf_source,
        "sampling": {"grid": [n, n], "cell_area_per_sample": dA, "odd_parity_columns": local["odd"]},
    }


def _areal(cell, yarn_vf: list[float], per_yarn: np.ndarray) -> dict:
    """The cell in plan and what it holds per area: the lattice's area (lx ly; a sheared cell's
    falls as cos of the shear at fixed spacings along the yarns), its shear angle [degrees], the
    yarns' and the fibres' volume per area [mm^3/mm^2 = mm] (the fibres' times their density is the
    areal density)."""
    area = cell.area
    fibres = float(np.dot(yarn_vf, per_yarn)) if yarn_vf is not None and len(yarn_vf) == len(per_yarn) else None
    return {"cell_area_mm2": float(area), "shear_angle_deg": cell.shear_angle,
            "yarn_volume_per_area_mm": float(per_yarn.sum()) / area,
            "fibre_volume_per_area_mm": None if fibres is None else fibres / area}


def _pair_overlaps(col: Columns, bot: np.ndarray, top: np.ndarray, xy: np.ndarray,
                   n_yarns: int) -> dict[tuple[int, int], tuple[float, float, list[float] | None]]:
    """Per overlapping yarn pair (a < b): (sum over points of the overlap length, its maximum, the
    point of the maximum)."""
    pairs: dict[tuple[int, int], tuple] = {}
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
        total = np.bincount(inverse, weights=o, minlength=len(keys))
        order = np.lexsort((o, inverse))  # per key, deepest last
        last = order[np.r_[np.flatnonzero(np.diff(inverse[order])), len(order) - 1]] if len(order) else order
        for key, v, k in zip(keys.tolist(), total, last):
            pair = (key // n_yarns, key % n_yarns)
            v0, d0, at0 = pairs.get(pair, (0.0, 0.0, None))
            pairs[pair] = (v0 + float(v), max(d0, float(o[k])),
                           at0 if d0 >= o[k] else [float(xy[pt[k], 0]), float(xy[pt[k], 1])])
    return pairs


# How the deepest overlap is sought between the grid's columns (`_deepest`): from the SEEDS deepest
# columns and each yarn pair's deepest, LEVELS steps of a pattern search (the 8 neighbours at half
# the grid's spacing, then a quarter, ...: 1/64 of it at the last). On TexGen's orthogonal weave
# (reference/models/ortho.tg3) the 200 x 200 grid's deepest column gives 0.0248 mm, the search
# 0.0301 mm, as a 41 x 41 scan of columns 0.0015 mm apart around the ridge does.
SEEDS, LEVELS = 16, 6


def _deepest(textile: Textile, n: int, depth: np.ndarray, xy: np.ndarray, pairs: dict, merged: dict,
             comm) -> tuple[float, list[float] | None, dict]:
    """The deepest overlap over the plane and its place, and the pairs with each one's deepest:
    the grid's (`merged`, `pairs`, on every rank) improved by a pattern search around the deepest
    columns (SEEDS, LEVELS); collective, every rank's share of the search's columns cast by it."""
    cell = textile.cell
    top_local = np.argsort(depth)[::-1][:SEEDS]
    seeds = [(float(depth[k]), [float(xy[k, 0]), float(xy[k, 1])]) for k in top_local if depth[k] > 0]
    if comm is not None and comm.size > 1:
        seeds = [s for part in comm.allgather(seeds) for s in part]
    seeds = sorted(seeds, key=lambda s: -s[0])[:SEEDS] + [(d, at) for _, d, at in pairs.values() if at is not None]
    best_depth, best_at = merged["max_depth"], merged["at"]
    if not seeds:
        return best_depth, best_at, pairs
    points = np.array([at for _, at in seeds], float)
    value = np.array([d for d, _ in seeds], float)
    step = np.array([cell.lx, cell.ly]) / n / 2
    moves = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1) if (i, j) != (0, 0)], float)
    n_yarns = len(textile.yarns)
    pairs = dict(pairs)
    parallel = comm is not None and comm.size > 1
    bins: dict = {}  # each yarn's triangles binned once for the LEVELS rounds (queries.columns)
    for _ in range(LEVELS):
        trial = cell.wrap((points[:, None, :] + moves[None] * step).reshape(-1, 2))
        mine = np.array_split(np.arange(len(trial)), comm.size)[comm.rank] if parallel else np.arange(len(trial))
        col = columns(textile, trial[mine], bins=bins)
        bot, top = _clipped(textile, col)
        flat = np.zeros(len(trial))
        flat[mine] = coverage_depth(len(mine), col.point, bot, top)
        parts = [_pair_overlaps(col, bot, top, trial[mine], n_yarns)]
        if parallel:
            from mpi4py import MPI

            flat = comm.allreduce(flat, op=MPI.SUM)
            parts = comm.allgather(parts[0])
        for part in parts:
            for key, (_, d, at) in part.items():
                v0, d0, _ = pairs.get(key, (0.0, 0.0, None))
                if d > d0:
                    pairs[key] = (v0, d, at)
        got = flat.reshape(len(points), len(moves))
        k = np.argmax(got, axis=1)
        better = got[np.arange(len(points)), k] > value
        points[better] = trial.reshape(len(points), len(moves), 2)[better, k[better]]
        value[better] = got[better, k[better]]
        step = step / 2
    j = int(np.argmax(value))
    if value[j] > best_depth:
        best_depth, best_at = float(value[j]), [float(points[j, 0]), float(points[j, 1])]
    return best_depth, best_at, pairs


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


def with_yarn_vf(textile: Textile, vf: float | None) -> Textile:
    """The model with every yarn's fibre data replaced by fibres that fill vf of its mean section
    [-] (the fibre area vf x A; `solve --yarn-vf`): the compaction law's phi0, the fibre volume its
    target Vf counts, the metrics' Vf and the corrected model's fibres then all read vf alike.
    None: the model as it is."""
    if vf is None:
        return textile
    check_yarn_vf(vf)
    return replace(textile, yarns=[replace(y, fibres=Fibres(area=vf * mean_section_area(y, textile.resolution)))
                                   for y in textile.yarns])
