"""The tet mesh's arrays made whole (mesher.py drives it): the nodes of each + face put exactly on
their partners' images (snap_periodic), flat tets refused (refuse_flat, FlatTets), and the fibre
direction of each yarn element (fibre_directions).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from textile_fenicsx.common.errors import GeometryError
from textile_fenicsx.model.textile import Textile

# A tet whose volume is at most this fraction of the box's is flat: the mesh is refused
FLAT = 1e-12


class FlatTets(GeometryError):
    """gmsh's mesh has flat tets; inside: none of them on a side of the box."""

    def __init__(self, message: str, inside: bool = False):
        super().__init__(message)
        self.inside = inside


def refuse_flat(name: str, points: np.ndarray, tets: np.ndarray, vol: np.ndarray, lo: np.ndarray,
                hi: np.ndarray) -> None:
    """FlatTets (a GeometryError) if any tet is flat (its volume at most FLAT of the box's), naming the
    flattest and whether it lies on a side of the box: where a yarn's surface runs along a side
    within 1e-5 mm, gmsh's own mesh has such tets (50 on ortho_w3f4, 4e-19 to 3e-12 mm^3)."""
    flat = vol <= FLAT * float(np.prod(hi - lo))
    if not np.any(flat):
        return
    k = int(np.argmin(vol))
    corners = points[tets[k]]
    where = ", ".join(f"{v:.3f}" for v in corners.mean(axis=0))
    near = 1e-6 * float(np.max(hi - lo))
    sides = [f"{sign}{'xyz'[ax]}" for ax in range(3) for sign, end in (("-", lo[ax]), ("+", hi[ax]))
             if np.any(np.abs(corners[:, ax] - end) <= near)]
    place = (f"on the box's {' and '.join(sides)} side: a yarn's surface runs along the side there, and gmsh "
             "cannot fill the sliver between them; use --kind voxel" if sides
             else "inside the box; try another --size, or use --kind voxel")
    raise FlatTets(f"the tet mesh of {name!r} has {int(np.sum(flat))} flat tets (volume at most {FLAT:g} of the "
                   f"box's), the flattest ({vol[k]:.2g} mm^3) at ({where}) mm {place}", inside=not sides)


def snap_periodic(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, faces: list) -> float:
    """Put every node of a + face exactly on the image of its - face partner (gmsh places the
    copies it makes on the + face's own geometry, which OCC cut to about 1e-7 mm of the - face's
    moved). faces: per axis, the rows of the nodes gmsh put on its + and - faces
    (volume_mesh._mesh_arrays); only those move. A node near a face but not on it is a yarn's: where a side cuts a leg
    lengthwise, its skin runs within 1e-5 mm of the face, and putting such nodes onto the face (or
    onto a face node's image) made 96 flat tets on ortho_w3f4. A + node moves onto the nearest -
    node within 1e-5 of the cell's size that no nearer + node claims; one left without is left
    where it is (the periodicity check reports it). Returns the largest move [mm]."""
    eps = 1e-9 * float(np.max(hi - lo))
    worst = 0.0
    for ax, plus, minus in faces:
        if not len(plus) or not len(minus):
            continue
        shift = np.zeros(3)
        shift[ax] = hi[ax] - lo[ax]
        points[minus, ax] = lo[ax]
        points[plus, ax] = hi[ax]
        d, j = cKDTree(points[minus]).query(points[plus] - shift)
        ok = d <= 1e4 * eps
        order = np.flatnonzero(ok)[np.argsort(d[ok], kind="stable")]
        _, first = np.unique(j[order], return_index=True)  # each - node to its nearest + node only
        mine = order[first]
        worst = max(worst, float(d[mine].max(initial=0.0)))
        points[plus[mine]] = points[minus[j[mine]]] + shift
    return worst


def fibre_directions(textile: Textile, points: np.ndarray, tets: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """Each element's unit fibre direction (E, 3): its yarn's at its centroid (0 in the matrix)."""
    fibre = np.zeros((len(tets), 3))
    centroids = points[tets].mean(axis=1)
    for i in range(len(textile.yarns)):
        k = phase == i + 1
        if np.any(k):
            fibre[k] = textile.fibre_direction(i, centroids[k])
    return fibre
