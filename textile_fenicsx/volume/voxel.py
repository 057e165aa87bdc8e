"""The voxel mesh: N x N x M hexahedra over the periodic cell, each of one phase read at its centre.

An element's phase is the yarn whose model contains its centre (vertical rays through the voxel
columns, periodic copies of the yarns included), or the matrix. A centre inside two or more yarns
(an overlap of the model, as in TexGen's idealised cells) is counted and reported, never hidden:
it goes to the yarn it lies deepest in, measured along the vertical ray (min(z - bottom, top - z)
of each yarn's interval), and mesh_report.json gives the number of such voxels, their volume and
the pairs of yarns involved. The mesh is periodic by construction (a structured grid over the box).
Its counts follow the size asked along each axis, or by default the rule of voxel_sizes.py, the grid
chosen near it for its yarn fraction (default_grid).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from textile_fenicsx.common import limits
from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.box import Box, VolumeMesh, element_fields, model_yarn_volumes, periodic_mismatch
from textile_fenicsx.volume.voxel_sizes import DEFAULT_MAX_VOXELS, Sizes, VoxelRule, default_sizes, union_fraction

log = logging.getLogger(__name__)

# Voxels a mesh may have (the bound of its own arrays; the memory estimate of what is built on it
# comes on top): 5e7 voxels are about 12 GB of index and field arrays.
MAX_VOXELS = 50_000_000
# a yarn's staircase error (its voxels, overlap included, against its model's volume) above which a
# grid that meets the default rule (voxel_sizes.py) is still said to be too coarse (issue 30: 3 %)
COARSE = 0.03
# The default grid's phase search (default_grid): steps of 2 % more voxels in plan and of 4 % through
# the thickness, and the yarn fraction error it stops at (0.25 %: Ex moves by about 1.1 % and Gxy by
# 1.7 % per % of it on the plain weave, docs/volume.md)
PHASE_STEPS = (7, 3)
PHASE_TOLERANCE = 0.0025
# A grid that meets the rule but whose voxels hold the model's yarn fraction more than 0.5 % off is
# warned about (on the plain weave 28 x 28 x 16, -0.57 %, gave Ex -2.2 % and Gxy -1.9 % where the
# rule's 27 x 27 x 16, +0.18 %, gave -1.3 % and -0.3 %), with the constants' change per unit of it
# measured there (grids of one height and different phases: Ex 1.1, Gxy 1.7, Ez 0.3; docs/volume.md)
PHASE_WARNING = 0.005
PER_FRACTION = {"Ex": 1.1, "Gxy": 1.7, "Ez": 0.3}


def voxel_counts(box: Box, size: float | Sequence[float], layers: int | None = None) -> tuple[int, int, int]:
    """Voxels along x, y, z for an element size [mm], one for every axis or (hx, hy, hz): the
    nearest whole numbers, at least one; along z `layers` where given (the same grid at every point
    of a compaction curve, stretched to each thickness)."""
    sizes = check_sizes(size)
    n = np.maximum(np.rint(box.size / np.array(sizes)), 1).astype(int)
    if layers is not None:
        n[2] = layers
    total = int(np.prod(n.astype(float)))
    if total > MAX_VOXELS:
        raise TextileError(f"volume mesh size {_text(sizes)} mm would give {n[0]} x {n[1]} x {n[2]} = {total:.3g} "
                           f"voxels, more than the limit of {MAX_VOXELS:.3g}; use a larger --size")
    return int(n[0]), int(n[1]), int(n[2])


def check_sizes(size: float | Sequence[float]) -> Sizes:
    """(hx, hy, hz) [mm] from one size for every axis or three, each checked (limits.check_length)."""
    values = np.ravel(np.asarray(size, dtype=object)).tolist()
    if len(values) not in (1, 3):
        raise TextileError(f"a voxel mesh takes one size H or three HX HY HZ [mm], got {len(values)}: "
                           f"{' '.join(str(v) for v in values)}")
    checked = [limits.check_length("volume mesh size", v) for v in values]
    hx, hy, hz = checked * 3 if len(checked) == 1 else checked
    return hx, hy, hz


def _text(sizes: Sizes) -> str:
    """'H' where the three sizes are one, else 'HX x HY x HZ'."""
    return f"{sizes[0]:g}" if len(set(sizes)) == 1 else " x ".join(f"{h:.4g}" for h in sizes)


def _grid(box: Box, counts: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Nodes (N, 3) and hexahedra (E, 8) of the structured grid, VTK order; element e = (ix ny + iy) nz + iz."""
    nx, ny, nz = counts
    axes = [np.linspace(box.lo[d], box.hi[d], counts[d] + 1) for d in range(3)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    points = np.column_stack((X.ravel(), Y.ravel(), Z.ravel()))
    node = np.arange(len(points)).reshape(nx + 1, ny + 1, nz + 1)
    c = node[:-1, :-1, :-1].ravel()
    dz, dy, dx = 1, nz + 1, (ny + 1) * (nz + 1)  # node offsets along each axis
    bottom = np.column_stack((c, c + dx, c + dx + dy, c + dy))
    return points, np.hstack((bottom, bottom + dz))


def classify(textile: Textile, box: Box, counts: tuple[int, int, int]) -> tuple[np.ndarray, dict, np.ndarray]:
    """The phase of every voxel (its centre), the overlap found and the voxels whose centres lie in
    each yarn, whichever yarn they went to: (phase (E,), overlap report, (n_yarns,) counts)."""
    nx, ny, nz = counts
    h = box.size / np.array(counts)
    xs = box.lo[0] + (np.arange(nx) + 0.5) * h[0]
    ys = box.lo[1] + (np.arange(ny) + 0.5) * h[1]
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    col = textile.columns(np.column_stack((X.ravel(), Y.ravel())))
    # every (column, yarn interval) covers the voxel centres z_k with bottom <= z_k <= top
    k_lo = np.maximum(np.ceil((col.bottom - box.lo[2]) / h[2] - 0.5), 0).astype(np.int64)
    k_hi = np.minimum(np.floor((col.top - box.lo[2]) / h[2] - 0.5), nz - 1).astype(np.int64)
    n = np.maximum(k_hi - k_lo + 1, 0)
    row = np.repeat(np.arange(len(n)), n)
    k = k_lo[row] + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    z = box.lo[2] + (k + 0.5) * h[2]
    depth = np.minimum(z - col.bottom[row], col.top[row] - z)
    voxel = col.point[row].astype(np.int64) * nz + k
    yarn = col.yarn[row]
    inside = np.bincount(yarn, minlength=len(textile.yarns))
    # the deepest yarn of each voxel wins; voxels seen by two or more yarns are the overlap
    order = np.lexsort((depth, voxel))
    voxel, yarn = voxel[order], yarn[order]
    last = np.r_[voxel[1:] != voxel[:-1], True]
    phase = np.zeros(nx * ny * nz, np.int32)
    phase[voxel[last]] = yarn[last] + 1
    seen = np.bincount(voxel, minlength=nx * ny * nz)
    # the yarns met in one voxel are neighbours in the sorted rows: count each such pair
    same = np.flatnonzero(voxel[1:] == voxel[:-1])
    a, b = np.minimum(yarn[same], yarn[same + 1]), np.maximum(yarn[same], yarn[same + 1])
    codes, counts_ = np.unique(a.astype(np.int64) * len(textile.yarns) + b, return_counts=True)
    pairs = {(int(c) // len(textile.yarns), int(c) % len(textile.yarns)): int(m) for c, m in zip(codes, counts_)}
    overlap = {"rule": "a voxel whose centre lies in two or more yarns goes to the one it lies deepest in "
                       "(along the vertical ray)",
               "voxels": int(np.sum(seen > 1)), "volume": float(np.sum(seen > 1) * np.prod(h)),
               "pairs": [{"yarns": [textile.yarns[i].name for i in k], "voxels": c} for k, c in sorted(pairs.items())]}
    return phase, overlap, inside


def default_grid(textile: Textile, box: Box, layers: int | None = None,
                 scale: float = 1.0) -> tuple[tuple[int, int, int], VoxelRule, dict[str, Any]]:
    """The default voxel counts of the textile's cell `box` (`layers` through the thickness where
    given), the rule they follow (voxel_sizes.default_sizes) and how they were chosen. Of the grids
    with up to PHASE_STEPS steps of 2 % more voxels in plan and of 4 % more through the thickness than
    the rule's (either way where the rule's grid was capped, none beyond DEFAULT_MAX_VOXELS), nearest
    the rule's first, the first whose voxels hold the model's yarn fraction within PHASE_TOLERANCE,
    else the nearest to it: a voxel's phase is read at its centre, and the grid's phase against the
    yarns moves their volume, and Ex and Gxy with it, by whole percent (docs/volume.md). scale: the
    sizes times this (a coarser or finer grid of the same rule, searched likewise, uncapped)."""
    rule = default_sizes(textile, box)
    base = np.array(voxel_counts(box, tuple(h * scale for h in rule.sizes), layers))
    exact = union_fraction(textile, box)
    if not exact > 0:  # no yarn in the box: no phase to choose
        return (int(base[0]), int(base[1]), int(base[2])), rule, {"model_yarn_fraction": exact}
    capped = rule.sizes != rule.rule
    plan = range(-PHASE_STEPS[0] if capped else 0, PHASE_STEPS[0] + 1)
    through = [0] if layers is not None else range(-PHASE_STEPS[1] if capped else 0, PHASE_STEPS[1] + 1)
    largest = max(DEFAULT_MAX_VOXELS, int(np.prod(base))) if scale == 1 else np.inf
    grids: set[tuple[int, int, int]] = set()
    for j in plan:
        for k in through:
            nx, ny, nz = np.maximum(np.ceil(base * np.array([1 + 0.02 * j, 1 + 0.02 * j, 1 + 0.04 * k]) - 1e-9), 1)
            if nx * ny * nz <= largest:
                grids.add((int(nx), int(ny), int(nz)))
    order = sorted(grids, key=lambda g: (abs(np.log(np.prod(g) / np.prod(base))), np.prod(g)))  # the rule's first
    errors: list[tuple[float, tuple[int, int, int]]] = []
    for g in order:
        errors.append((float(np.mean(classify(textile, box, g)[0] > 0)) / exact - 1, g))
        if abs(errors[-1][0]) <= PHASE_TOLERANCE:
            break
    error, counts = min(errors, key=lambda e: abs(e[0]))
    return counts, rule, {"model_yarn_fraction": exact, "start_grid": list(order[0]),  # the rule's, or capped
                          "start_grid_fraction_error": errors[0][0], "fraction_error": error,
                          "grids_tried": len(errors), "tolerance": PHASE_TOLERANCE}


def voxel_mesh(textile: Textile, box: Box, size: float | Sequence[float] | None, yarn_vf: list[float],
               layers: int | None = None, scale: float = 1.0) -> VolumeMesh:
    """The voxel mesh of the textile over the box at element size `size` [mm] (module docstring):
    one for every axis, (hx, hy, hz), or None for the default rule (default_sizes); `layers` voxels
    through the thickness where given; yarn_vf: each yarn's intra-yarn fibre volume fraction; scale:
    the sizes, given or default, times this (volume/refinement.py's meshes)."""
    start = time.perf_counter()
    if size is None:
        counts, rule, phase_search = default_grid(textile, box, layers, scale)
        exact = phase_search["model_yarn_fraction"]
    else:
        rule, phase_search = default_sizes(textile, box), None
        counts = voxel_counts(box, [h * scale for h in check_sizes(size)], layers)
        exact = union_fraction(textile, box)
    voxel: Sizes = tuple(float(h) for h in box.size / np.array(counts))  # type: ignore[assignment]
    log.info("voxel mesh: %d x %d x %d = %d voxels of %.3g x %.3g x %.3g mm", *counts, int(np.prod(counts)), *voxel)
    phase, overlap, inside = classify(textile, box, counts)
    fraction_error = float(np.mean(phase > 0)) / exact - 1 if exact > 0 else 0.0
    points, cells = _grid(box, counts)
    centres = points[cells].mean(axis=1)
    direction, vf = element_fields(textile, centres, phase, yarn_vf)
    mesh = VolumeMesh("voxel", box, points, cells, phase, direction, vf, [y.name for y in textile.yarns])
    model = model_yarn_volumes(textile, box)
    meshed = mesh.phase_volumes()[1:]
    mesh.report = {
        "kind": "voxel", "voxels": list(counts), "elements": len(cells), "nodes": len(points),
        "quality": {"min": 1.0, "mean": 1.0, "measure": "voxels are boxes"},
        "overlap": overlap,
        "yarns": [{"name": y.name, "meshed_volume": float(m), "model_volume": float(v),
                   "relative_error": float(m / v - 1) if v > 0 else None,
                   "staircase_error": float(c * np.prod(voxel) / v - 1) if v > 0 else None}
                  for y, m, v, c in zip(textile.yarns, meshed, model, inside)],
        "periodicity": periodic_mismatch(points, box),
        "sizes": {"voxel_mm": list(voxel), "asked_mm": None if size is None else list(check_sizes(size)),
                  "scale": scale,
                  "layers": layers, **rule.report(voxel), "model_yarn_fraction": exact,
                  "yarn_fraction_error": fraction_error, "phase": phase_search},
        "seconds": time.perf_counter() - start,
    }
    if overlap["voxels"]:
        log.warning("voxel mesh: %d voxels (%.4g mm^3) lie in two or more yarns; each went to the yarn it lies "
                    "deepest in (mesh_report.json: overlap)", overlap["voxels"], overlap["volume"])
    short = rule.short(voxel, default=size is None)
    if short and scale > 1:  # a coarser mesh for an error estimate: expected
        log.info("voxel mesh (coarser, for the error estimate): %s", short)
    elif short:
        log.warning("voxel mesh: %s", short)
    elif abs(fraction_error) > PHASE_WARNING:  # a grid that meets the rule, at a poor phase
        log.warning("voxel mesh: the voxels' yarn fraction is %+.1f %% off the model's (%.4f): expect Ex off by "
                    "about %.1f %% and Gxy by %.1f %% more from it alone (docs/volume.md); give another --size, "
                    "or none: the default grid holds it within %.2g %%", 100 * fraction_error, exact,
                    100 * PER_FRACTION["Ex"] * abs(fraction_error), 100 * PER_FRACTION["Gxy"] * abs(fraction_error),
                    100 * PHASE_TOLERANCE)
    errors = [(abs(y["staircase_error"]), y["name"]) for y in mesh.report["yarns"] if y["staircase_error"] is not None]
    worst, name = max(errors, default=(0.0, ""))
    if worst > COARSE and not short and abs(fraction_error) <= PHASE_WARNING:  # a yarn's own voxels, overlap included
        log.warning("voxel mesh: %s's voxels are %.1f %% off its model's volume (voxels %.3g mm tall); give a "
                    "smaller --size", name, 100 * worst, voxel[2])
    log.info("voxel mesh: %d elements in %.2f s", len(cells), mesh.report["seconds"])
    return mesh
