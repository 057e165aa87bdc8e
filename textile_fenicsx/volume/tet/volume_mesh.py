"""The volume mesh of a tet mesh's box, read back as arrays (mesher.py drives it): gmsh's 3D mesh of
the surfaces surface_mesh.py meshed, made once more with the box moved where it fails on a side of
the box, then optimised; its nodes, tets, phases and the nodes on the box's periodic faces.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from textile_fenicsx.common.errors import GeometryError
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.tet import sides
from textile_fenicsx.volume.tet.options import TetOptions
from textile_fenicsx.volume.tet.report import model_volumes
from textile_fenicsx.volume.tet.surface_mesh import PAIR_TOLERANCE, model_nodes, session, skin_sections, traced

log = logging.getLogger(__name__)

# gmsh's optimisers run on the volume mesh after its own (Mesh.Optimize 1, inside generate).
# Without that first pass the satin's mesh took 3 s less of 13 for the same quality (minSICN
# 0.014), but over the family the worst tet got worse (ours_orthogonal's minSICN 0.0023 instead of
# 0.0118, basket3's 0.0050 instead of 0.0098): kept.
OPTIMISE = ("Relocate3D", "")


def generate(textile: Textile, options: TetOptions, gap: float, shrink: float, height: float, times: dict,
             folder: str):
    """Build, mesh and read back the model (gmsh initialised, a model current): the surfaces
    (surface_mesh.traced), then the volume. Where gmsh's volume mesh fails on facets of a side of
    the box across x or y, the box moves once along that axis, its sides there farthest from the
    edges of the yarns running along them (sides.clear_of_edges), and the model is built again.
    Returns the arrays, box, pairs, how many times the points were doubled and the elements per
    2 pi of curvature."""
    import gmsh

    model = model_volumes(textile) * (1 - shrink) ** 2
    lo, hi, pairs, phase_of, move, attempt, curvature = traced(textile, options, gap, shrink, height, times, folder,
                                                               np.zeros(3), model)
    t = time.perf_counter()
    try:
        gmsh.model.mesh.generate(3)
    except Exception as e:
        tol = PAIR_TOLERANCE * float(np.max(hi - lo))
        axis = _side_of(str(e), lo, hi, tol)
        if axis is None:
            raise
        places = [d for d in sides.clear_of_edges(textile, skin_sections(textile, options, shrink), lo - move,
                                                  hi - move, axis) if abs(d - move[axis]) > tol]
        if not places:
            raise
        shifted = move.copy()
        shifted[axis] = places[0]
        log.warning("tet: gmsh's volume mesh failed on the box's side across %s (%s): the box moved by (%.4g, %.4g) "
                    "mm, its sides there farthest from the edges of the yarns along them", "xy"[axis], e,
                    shifted[0], shifted[1])
        # a failed generate leaves gmsh's mesh lock held: every later mesh call would return at once
        # ("I'm busy! Ask me that later"), meshing nothing. A new session releases it
        gmsh.finalize()
        gmsh.initialize(interruptible=False)
        session(options)
        gmsh.model.add(f"tet-{textile.name}")
        lo, hi, pairs, phase_of, move, attempt, curvature = traced(textile, options, gap, shrink, height, times,
                                                                   folder, shifted, model)
        t = time.perf_counter()
        gmsh.model.mesh.generate(3)
    for method in OPTIMISE:
        gmsh.model.mesh.optimize(method)
    times["volume_s"] = time.perf_counter() - t
    log.info("tet: volume mesh and optimisation %.1f s", times["volume_s"])
    return _mesh_arrays(phase_of, pairs), lo, hi, pairs, attempt, curvature


def _side_of(message: str, lo: np.ndarray, hi: np.ndarray, tol: float) -> int | None:
    """The axis (0: x, 1: y) of the box's side that one of the surfaces a gmsh error names lies on
    ("... on surface 4622 surface 3562"), to tol [mm], or None."""
    import re

    import gmsh

    for tag in map(int, re.findall(r"surface (\d+)", message)):
        try:
            box = np.array(gmsh.model.getBoundingBox(2, tag))
        except Exception:  # not a surface of the model (any more)
            continue
        for ax in (0, 1):
            if box[ax + 3] - box[ax] < tol and min(abs(box[ax] - lo[ax]), abs(box[ax] - hi[ax])) < tol:
                return ax
    return None


def _mesh_arrays(phase_of: dict[int, int], pairs: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """Nodes (N, 3), tets (E, 4) and phases (E,) of the current gmsh model, positively oriented,
    and per periodic axis of `pairs` the rows of the nodes gmsh put on the box's + and - faces."""
    import gmsh

    points, index = model_nodes()
    tets: list[np.ndarray] = []
    phase: list[np.ndarray] = []
    for vol, ph in sorted(phase_of.items()):
        types, _, nodes = gmsh.model.mesh.getElements(3, vol)
        for t, nd in zip(types, nodes):
            if t != 4:
                raise GeometryError(f"gmsh made elements of type {t} in volume {vol}, not linear tets")
            tets.append(index[nd.astype(np.int64)].reshape(-1, 4))
            phase.append(np.full(len(tets[-1]), ph, np.int32))
    used, inverse = np.unique(np.concatenate(tets), return_inverse=True)
    row = np.full(len(points), -1, np.int64)
    row[used] = np.arange(len(used))

    def on(surfaces) -> np.ndarray:  # rows of these surfaces' nodes (curves and corners included; none in no tet)
        tags = [gmsh.model.mesh.getNodes(2, int(f), includeBoundary=True)[0] for f in surfaces]
        rows = row[np.unique(index[np.concatenate(tags + [np.zeros(0)]).astype(np.int64)])]
        return rows[rows >= 0]

    faces = [(axis, on(slaves), on(masters)) for axis, slaves, masters, _, _ in pairs]
    return points[used], inverse.reshape(-1, 4), np.concatenate(phase), faces
