"""The tet mesh's element sizes (mesher.py drives it): on a grid of the box, grading x (the distance
to the nearest yarn + the distance to the nearest other yarn), between the smallest size and the
largest, so that the gap sheets between the yarns get elements fitted to them; given to gmsh as
its background field (background).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.tet import solids
from textile_fenicsx.volume.tet.options import TetOptions, smallest


def size_grid(textile: Textile, lo: np.ndarray, hi: np.ndarray, options: TetOptions, gap: float,
              shrink: float, height: float) -> tuple[list[np.ndarray], np.ndarray]:
    """The element size on a grid of the box: grading x (distance to the nearest yarn + distance to
    the nearest other yarn), in [gap / 2, size]. Distances are to the yarns' section points (and to
    their images by the box's periods, z too), point-to-plane with the points' normals. Returns the
    grid's axes and the sizes (nx, ny, nz)."""
    H, c = options.size, options.grading
    pts, nrm, lab = [], [], []
    for i in range(len(textile.yarns)):
        for sec in solids.chains(textile, i, lo, hi, options.spacing / 2, 2 * options.points, shrink, margin=1):
            along = np.gradient(sec, axis=0)
            around = np.roll(sec, -1, axis=1) - np.roll(sec, 1, axis=1)
            n = np.cross(along, around)
            n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)
            pts.append(sec.reshape(-1, 3))
            nrm.append(n.reshape(-1, 3))
            lab.append(np.full(sec.shape[0] * sec.shape[1], i))
    P, N, Lb = np.concatenate(pts), np.concatenate(nrm), np.concatenate(lab)
    L = hi - lo
    shifts = [np.array([a * L[0], b * L[1], e * L[2]]) for a in (-1, 0, 1) for b in (-1, 0, 1) for e in (-1, 0, 1)]
    P = np.concatenate([P + s for s in shifts])
    N, Lb = np.tile(N, (len(shifts), 1)), np.tile(Lb, len(shifts))
    near = np.all((P > lo - H / c) & (P < hi + H / c), axis=1)
    P, N, Lb = P[near], N[near], Lb[near]
    step_xy, step_z = H / 3, max(min(H / 3, gap), H / 10)
    steps = ((0, step_xy), (1, step_xy), (2, step_z))
    axes = [np.linspace(lo[k], hi[k], max(int(np.ceil(L[k] / s)) + 1, 2)) for k, s in steps]
    G = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    k = 16
    d, j = cKDTree(P).query(G, k=k, distance_upper_bound=H / c, workers=options.threads)
    found = np.isfinite(d)
    j = np.minimum(j, len(P) - 1)
    plane = np.abs(np.einsum("gkc,gkc->gk", G[:, None, :] - P[j], N[j]))
    dist = np.where(found, np.minimum(d, np.maximum(plane, d - options.spacing)), np.inf)
    lab_k = np.where(found, Lb[j], -1)
    first = np.argmin(dist, axis=1)
    d1 = dist[np.arange(len(G)), first]
    other = found & (lab_k != lab_k[np.arange(len(G)), first][:, None])
    d2 = np.where(other, dist, np.inf).min(axis=1)
    d2 = np.where(other.any(axis=1), d2, np.where(found[:, -1], d[:, -1], np.inf))
    h = np.clip(c * (d1 + d2), smallest(options, gap, height), H)
    return axes, np.where(np.isfinite(h), h, H).reshape([len(a) for a in axes])


def background(axes: list[np.ndarray], h: np.ndarray, folder: str) -> None:
    """The sizes as gmsh's background field: a Structured field (trilinear on the grid, read from a
    text file in `folder`: origin, steps, counts, then the values with z fastest; a view of
    hexahedra did the same 15 times slower)."""
    import gmsh

    path = Path(folder) / "sizes.txt"
    with open(path, "w") as f:
        f.write(" ".join(f"{a[0]:.17g}" for a in axes) + "\n")
        f.write(" ".join(f"{a[1] - a[0]:.17g}" for a in axes) + "\n")
        f.write(" ".join(str(len(a)) for a in axes) + "\n")
        f.write("\n".join(f"{v:.6g}" for v in h.reshape(-1)) + "\n")
    field = gmsh.model.mesh.field.add("Structured")
    gmsh.model.mesh.field.setString(field, "FileName", str(path))
    gmsh.model.mesh.field.setNumber(field, "TextFormat", 1)
    gmsh.model.mesh.field.setAsBackgroundMesh(field)
