"""Yarn surfaces as one triangle mesh, clipped to the cell in numpy; built once per textile and
shared by the exports, the figures and the checks.

Each yarn is a closed tube (its stations' section polygons, periodic copies chained so that they
cover the cell, capped at both ends). Clipping by a plane is done on all triangles at once: a
triangle inside stays, one outside goes, one that the plane crosses is cut into one or two (the
new points are computed once per edge, so neighbours share them). The cut edges form loops on the
plane, which are capped by ear clipping, so every yarn stays a closed surface; the cost is linear
in the triangles (and in the loops' length squared for the caps). A yarn whose cut cannot be
capped (the tube crosses itself at the plane) keeps its clipped, open surface and is listed in
`open_yarns`: an export never fails on it.
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from textile_fenicsx.common.files import atomic_path
from textile_fenicsx.model.textile import Resolution, Textile

# The resolution of the surfaces a run writes and draws (STL, VTU, pictures): stations 0.25 mm
# apart (at least one per master node), 32 points a section (0.6 % of a section's area); the
# metrics use the models' own, finer ones.
EXPORT = Resolution(spacing=0.25, section_points=32, per_segment=1)

__all__ = ["EXPORT", "YarnSurfaces", "clip_closed", "is_closed"]



@dataclass
class YarnSurfaces:
    """All yarns' surfaces: points (N, 3) [mm], triangles (M, 3) with outward normals, the yarn of
    each triangle (M,), and the yarns whose clipped surface is not closed."""

    points: np.ndarray
    triangles: np.ndarray
    yarn: np.ndarray
    open_yarns: list = field(default_factory=list)

    @classmethod
    def build(cls, textile: Textile, clip: bool = True, resolution=None) -> "YarnSurfaces":
        """The textile's yarn surfaces, clipped to its cell (and z range) when `clip`; at the
        textile's own resolution, or at `resolution` (textile.Resolution)."""
        if resolution is not None:
            textile = Textile(textile.cell, textile.yarns, textile.name, resolution, textile.tiling)
        planes = _cell_planes(textile) if clip else []
        points, triangles, yarn, open_yarns, offset = [], [], [], [], 0
        for i in range(len(textile.yarns)):
            closed = True
            for pts, faces in textile.tubes(i):
                for normal, value in planes:
                    if len(faces) == 0:
                        break
                    pts, faces, capped = clip_closed(pts, faces, normal, value)
                    closed &= capped
                if len(faces) == 0:
                    continue
                used, compact = np.unique(faces.ravel(), return_inverse=True)
                points.append(pts[used])
                triangles.append(compact.reshape(-1, 3) + offset)
                yarn.append(np.full(len(faces), i))
                offset += len(used)
            if not closed:
                open_yarns.append(i)
        if not points:
            return cls(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), open_yarns)
        return cls(np.vstack(points), np.vstack(triangles), np.concatenate(yarn), open_yarns)

    def volumes(self, n_yarns: int) -> np.ndarray:
        """Each yarn's enclosed volume [mm^3] (divergence theorem; meaningful for closed yarns)."""
        p = self.points[self.triangles]
        signed = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])) / 6
        return np.bincount(self.yarn, weights=signed, minlength=n_yarns)

    def polydata(self):
        """A pyvista PolyData with the yarn index as cell data."""
        import pyvista

        mesh = pyvista.PolyData(self.points, np.hstack([np.full((len(self.triangles), 1), 3),
                                                         self.triangles]).ravel())
        mesh.cell_data["yarn"] = self.yarn
        return mesh

    def write(self, path) -> Path:
        """Write to `path` atomically: binary STL, or (any other suffix meshio knows, e.g. .vtu)
        with the yarn index as cell data."""
        import meshio

        path = Path(path)
        cells = [("triangle", self.triangles)]
        with atomic_path(path) as tmp:
            if path.suffix.lower() == ".stl":
                meshio.write(tmp, meshio.Mesh(self.points, cells), file_format="stl", binary=True)
            else:
                meshio.write(tmp, meshio.Mesh(self.points, cells, cell_data={"yarn": [self.yarn.astype(np.int32)]}),
                             file_format=meshio.extension_to_filetypes[path.suffix.lower()][0])
        return path


def _cell_planes(textile: Textile) -> list[tuple[np.ndarray, float]]:
    """(normal, value): keep n . x >= value, for the cell's sides (and its z range)."""
    x0, x1, y0, y1 = textile.cell.bounds
    planes = [((1, 0, 0), x0), ((-1, 0, 0), -x1), ((0, 1, 0), y0), ((0, -1, 0), -y1)]
    if textile.cell.z_range is not None:
        planes += [((0, 0, 1), textile.cell.z_range[0]), ((0, 0, -1), -textile.cell.z_range[1])]
    return [(np.array(n, float), float(v)) for n, v in planes]


def is_closed(faces: np.ndarray) -> bool:
    """Is the triangle set a closed 2-manifold: every edge used by exactly two triangles, once in
    each direction?"""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    fwd = np.unique(edges, axis=0, return_counts=True)
    if np.any(fwd[1] != 1):
        return False
    rev = np.unique(edges[:, ::-1], axis=0)
    return len(rev) == len(fwd[0]) and np.array_equal(rev, fwd[0])


def clip_closed(pts: np.ndarray, faces: np.ndarray, normal: np.ndarray, value: float):
    """Keep the part of a closed triangulated surface with normal . x >= value and cap the cut.
    Returns (points, faces, capped): capped is False when the cut loops could not be capped (the
    surface is then returned clipped and open)."""
    d = pts @ normal - value
    inside = d >= 0
    count = inside[faces].sum(axis=1)
    if np.all(count == 3):
        return pts, faces, True
    keep = [faces[count == 3]]
    # rotate each cut triangle so that its odd vertex (alone on its side) comes first
    cut = faces[(count == 1) | (count == 2)]
    single = np.where(inside[cut].sum(axis=1) == 1, 1, 0)  # the odd vertex is inside (1) or outside (0)
    odd = np.argmax(inside[cut] == single[:, None].astype(bool), axis=1)
    rolled = np.take_along_axis(cut, (odd[:, None] + np.arange(3)) % 3, axis=1)
    a, b, c = rolled.T
    # one new point per crossed edge, computed from its endpoints in a fixed order
    edges = np.concatenate([np.column_stack((a, b)), np.column_stack((a, c))])
    edges = np.sort(edges, axis=1)
    unique, index = np.unique(edges, axis=0, return_inverse=True)
    i, j = unique.T
    t = d[i] / (d[i] - d[j])
    new = pts[i] + t[:, None] * (pts[j] - pts[i])
    p_ab, p_ac = len(pts) + index[:len(a)], len(pts) + index[len(a):]
    pts = np.vstack((pts, new))
    one = single == 1  # a inside: the triangle (a, p_ab, p_ac); cut edge p_ab -> p_ac
    keep.append(np.column_stack((a[one], p_ab[one], p_ac[one])))
    two = ~one  # a outside, b and c inside: the quadrilateral b, c, p_ac, p_ab; cut edge p_ac -> p_ab
    keep.append(np.column_stack((b[two], c[two], p_ac[two])))
    keep.append(np.column_stack((b[two], p_ac[two], p_ab[two])))
    loop_edges = np.concatenate([np.column_stack((p_ab[one], p_ac[one])), np.column_stack((p_ac[two], p_ab[two]))])
    faces = np.vstack(keep)
    caps = _caps(pts, loop_edges, normal)
    if caps is None:
        return pts, faces, False
    return pts, np.vstack((faces, caps)), True


def _caps(pts: np.ndarray, edges: np.ndarray, normal: np.ndarray) -> np.ndarray | None:
    """Triangles closing the directed cut edges' loops (None when they do not form simple loops)."""
    if len(edges) == 0:
        return np.zeros((0, 3), np.int64)
    start, end = edges.T
    if len(np.unique(start)) != len(start) or len(np.unique(end)) != len(end) \
            or not np.array_equal(np.sort(start), np.sort(end)):
        return None
    following = dict(zip(start.tolist(), end.tolist()))
    # the plane's own axes: the caps' normals must point against `normal` (out of the kept side)
    e1 = np.cross(normal, [0.0, 0.0, 1.0] if abs(normal[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    out, seen = [], set()
    for first in start.tolist():
        if first in seen:
            continue
        loop = [first]
        while True:
            seen.add(loop[-1])
            nxt = following[loop[-1]]
            if nxt == first:
                break
            loop.append(nxt)
        ring = np.array(loop[::-1])  # the cap runs against the cut edges
        tris = _ear_clip(np.column_stack((pts[ring] @ e1, pts[ring] @ e2)))
        if tris is None:
            return None
        out.append(ring[tris])
    return np.vstack(out)


def _ear_clip(xy: np.ndarray) -> np.ndarray | None:
    """Triangles (local indices) of a simple polygon, kept in its own orientation (None if it is not
    simple enough to clip)."""
    n = len(xy)
    if n < 3:
        return np.zeros((0, 3), np.int64)
    area = 0.5 * np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])
    sign = 1.0 if area >= 0 else -1.0
    idx = list(range(n))
    tris = []
    guard = 0
    k = 0
    while len(idx) > 3:
        m = len(idx)
        i0, i1, i2 = idx[(k - 1) % m], idx[k % m], idx[(k + 1) % m]
        a, b, c = xy[i0], xy[i1], xy[i2]
        cross = sign * ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))
        ear = cross > 0
        if ear:
            others = np.array([j for j in idx if j not in (i0, i1, i2)])
            if len(others):
                p = xy[others]
                d1 = sign * ((b[0] - a[0]) * (p[:, 1] - a[1]) - (b[1] - a[1]) * (p[:, 0] - a[0]))
                d2 = sign * ((c[0] - b[0]) * (p[:, 1] - b[1]) - (c[1] - b[1]) * (p[:, 0] - b[0]))
                d3 = sign * ((a[0] - c[0]) * (p[:, 1] - c[1]) - (a[1] - c[1]) * (p[:, 0] - c[0]))
                ear = not np.any((d1 > 0) & (d2 > 0) & (d3 > 0))
        if ear:
            tris.append((i0, i1, i2))
            idx.pop(k % m)
            guard = 0
        else:
            k += 1
            guard += 1
            if guard > len(idx):  # no ear left: degenerate (collinear) points; fan the rest
                tris += [(idx[0], idx[j], idx[j + 1]) for j in range(1, len(idx) - 1)]
                idx = idx[:3]
                break
    if len(idx) == 3:
        tris.append((idx[0], idx[1], idx[2]))
    return np.array(tris, np.int64)
