"""Exports of yarn surfaces (meshio: VTU, STL) with the yarn index as cell data."""

from pathlib import Path

import meshio
import numpy as np

from textile_fenicsx.files import atomic_path
from textile_fenicsx.textile import Textile


def surfaces(textile: Textile, clip: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All yarn surfaces as one triangle soup: points (N, 3), triangles (M, 3), yarn index (M,)."""
    points, tris, index = [], [], []
    offset = 0
    for i in range(len(textile.yarns)):
        poly = textile.surface(i, clip=clip)
        if poly.n_points == 0:
            continue
        faces = poly.faces.reshape(-1, 4)[:, 1:]
        points.append(np.asarray(poly.points, float))
        tris.append(faces + offset)
        index.append(np.full(len(faces), i))
        offset += poly.n_points
    return np.vstack(points), np.vstack(tris), np.concatenate(index)


def write_surfaces(textile: Textile, path, clip: bool = True) -> Path:
    """Write yarn surfaces to `path` (format by suffix: .vtu, .stl, ...), atomically."""
    path = Path(path)
    points, tris, index = surfaces(textile, clip)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".stl":
            meshio.write(tmp, meshio.Mesh(points, [("triangle", tris)]), file_format="stl", binary=True)
        else:
            cell_data = {"yarn": [index.astype(np.int32)]}
            meshio.write(tmp, meshio.Mesh(points, [("triangle", tris)], cell_data=cell_data))
    return path
