"""The voxel mesh: N x N x M hexahedra over the periodic cell, each of one phase read at its centre.

An element's phase is the yarn whose model contains its centre (vertical rays through the voxel
columns, periodic copies of the yarns included), or the matrix. A centre inside two or more yarns
(an overlap of the model, as in TexGen's idealised cells) is counted and reported, never hidden:
it goes to the yarn it lies deepest in, measured along the vertical ray (min(z - bottom, top - z)
of each yarn's interval), and mesh_report.json gives the number of such voxels, their volume and
the pairs of yarns involved. The mesh is periodic by construction (a structured grid over the box).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from textile_fenicsx.common import limits
from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.box import Box, VolumeMesh, element_fields, model_yarn_volumes, periodic_mismatch

log = logging.getLogger(__name__)

# Voxels a mesh may have (the bound of its own arrays; the memory estimate of what is built on it
# comes on top): 5e7 voxels are about 12 GB of index and field arrays.
MAX_VOXELS = 50_000_000
COARSE = 0.03  # a yarn volume error above which the size is said to be too coarse (issue 30: 3 %)


def voxel_counts(box: Box, size: float, layers: int | None = None) -> tuple[int, int, int]:
    """Voxels along x, y, z for an element size [mm]: the nearest whole numbers, at least one; along
    z `layers` where given (the same grid at every point of a compaction curve, stretched to each
    thickness)."""
    size = limits.check_length("volume mesh size", size)
    n = np.maximum(np.rint(box.size / size), 1).astype(int)
    if layers is not None:
        n[2] = layers
    total = int(np.prod(n.astype(float)))
    if total > MAX_VOXELS:
        raise TextileError(f"volume mesh size {size:g} mm would give {n[0]} x {n[1]} x {n[2]} = {total:.3g} voxels, "
                           f"more than the limit of {MAX_VOXELS:.3g}; use a larger --size")
    return int(n[0]), int(n[1]), int(n[2])


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


def classify(textile: Textile, box: Box, counts: tuple[int, int, int]) -> tuple[np.ndarray, dict]:
    """The phase of every voxel (its centre) and the overlap found: (phase (E,), overlap report)."""
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
    return phase, overlap


def voxel_mesh(textile: Textile, box: Box, size: float, yarn_vf: list[float], layers: int | None = None) -> VolumeMesh:
    """The voxel mesh of the textile over the box at element size `size` [mm] (module docstring),
    `layers` voxels through the thickness where given; yarn_vf: each yarn's intra-yarn fibre volume
    fraction."""
    counts = voxel_counts(box, size, layers)
    start = time.perf_counter()
    log.info("voxel mesh: %d x %d x %d = %d voxels of %.3g x %.3g x %.3g mm", *counts, int(np.prod(counts)),
             *(box.size / np.array(counts)))
    phase, overlap = classify(textile, box, counts)
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
                   "relative_error": float(m / v - 1) if v > 0 else None}
                  for y, m, v in zip(textile.yarns, meshed, model)],
        "periodicity": periodic_mismatch(points, box),
        "seconds": time.perf_counter() - start,
    }
    if overlap["voxels"]:
        log.warning("voxel mesh: %d voxels (%.4g mm^3) lie in two or more yarns; each went to the yarn it lies "
                    "deepest in (mesh_report.json: overlap)", overlap["voxels"], overlap["volume"])
    errors = [(abs(y["relative_error"]), y["name"]) for y in mesh.report["yarns"] if y["relative_error"] is not None]
    worst, name = max(errors, default=(0.0, ""))
    if worst > COARSE:
        log.warning("voxel mesh: %s's meshed volume is %.1f %% off its model's (voxels %.3g mm tall): the yarns "
                    "are a few voxels thick at most; give a smaller --size", name, 100 * worst,
                    (box.size / np.array(counts))[2])
    log.info("voxel mesh: %d elements in %.2f s", len(cells), mesh.report["seconds"])
    return mesh
