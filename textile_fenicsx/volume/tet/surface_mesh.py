"""The gmsh model of a tet mesh's box and its surface mesh (mesher.py drives it; volume_mesh.py
meshes the volume after it): gmsh's session, the yarn solids (solids.py) in the box, moved where
OCC's cut loses a yarn or leaves faces unpaired (sides.py), the periodic faces and the sizes
(sizes.py), then the surface mesh: made again with the sections traced with more points where it
crosses itself, and with more elements per 2 pi of curvature where it loses a yarn's volume.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from textile_fenicsx.common.errors import MeshError
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.tet import checks, sides, solids
from textile_fenicsx.volume.tet.options import TetOptions, box_corners, check_size, smallest
from textile_fenicsx.volume.tet.report import LOST
from textile_fenicsx.volume.tet.sizes import background, size_grid

log = logging.getLogger(__name__)

# How far apart [fraction of the box] the bounding boxes of two faces paired as periodic may be: OCC's
# boxes of spline faces are loose (the faces are then checked by the mesh's periodicity).
PAIR_TOLERANCE = 5e-4
# Relative accuracy of gmsh's integral of the size field along each curve, which places the
# curves' nodes (its default 1e-9). On the corrected satin at 0.35 mm the curves took 27 s with
# 1e-9, 19 s with 1e-6, 6 s with 1e-4, for the same mesh to gmsh's run-to-run variation (276 105,
# 276 135, 276 198 tets, minSICN 0.0145, 0.0145, 0.0144, yarn volumes within 0.50 %). 1e-3 took
# 3.5 s for the same satin mesh, but over the family the worst tets got worse (basket3's minSICN
# 0.0050 instead of 0.0098, satin4 w0.9 h0.2's 0.0033 instead of 0.0115): not taken.
LC_PRECISION = 1e-4
# Times the sections are traced again with twice the points when the surface mesh crosses itself.
RETRACE = 2
# The surfaces are meshed again with twice the elements per 2 pi of curvature, up to CURVATURE_STEPS
# times, while a yarn's surface mesh encloses more than SHORT (a fraction) below its model's volume
# (the criterion is 1 %; one doubling took the lenticular satin from 1.05 % to 0.84 %, a second to 0.35 %)
CURVATURE_STEPS = 2
SHORT = 0.009
# Places the box may move to, past the cell's origin, where OCC's cut of a skin by the box gives
# nothing or leaves the faces of two sides unpaired (sides.moves)
MOVES = 3


def session(options: TetOptions) -> None:
    """gmsh's options for a tet mesh that hold for its whole session."""
    import gmsh

    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", min(int(options.threads), 2))
    gmsh.option.setNumber("Geometry.OCCParallel", 1)


def mesh_surfaces() -> None:
    """gmsh's surface mesh of the model. The Structured size field (sizes.background) reads its file
    at its first use, unguarded: two threads meshing curves at once both read it, and one frees
    what the other reads (a segfault in gmsh 4.13). So the curves are meshed on one thread, which reads
    the file, and the surfaces on every thread. The curves' size integral is taken to LC_PRECISION
    (the session's own value is put back: the plate mesher shares the session)."""
    import gmsh

    threads = gmsh.option.getNumber("General.NumThreads")
    precision = gmsh.option.getNumber("Mesh.LcIntegrationPrecision")
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.option.setNumber("Mesh.LcIntegrationPrecision", LC_PRECISION)
    try:
        gmsh.model.mesh.generate(1)
    finally:
        gmsh.option.setNumber("General.NumThreads", threads)
        gmsh.option.setNumber("Mesh.LcIntegrationPrecision", precision)
    gmsh.model.mesh.generate(2)


def model_nodes() -> tuple[np.ndarray, np.ndarray]:
    """The current gmsh model's nodes (N, 3) and the row of each node tag (-1: no such tag)."""
    import gmsh

    tags, xyz, _ = gmsh.model.mesh.getNodes()
    index = np.full(int(tags.max()) + 1, -1, np.int64)
    index[tags.astype(np.int64)] = np.arange(len(tags))
    return xyz.reshape(-1, 3), index


def _crossings(phase_of: dict[int, int]) -> tuple[np.ndarray, tuple[int, ...]]:
    """Where the current gmsh model's surface triangles cross (checks.surface_crossings), and the
    phases of the first two crossing triangles (the yarn each bounds, 0 the box)."""
    import gmsh

    points, index = model_nodes()
    triangles, surface = [], []
    for _, s in gmsh.model.getEntities(2):
        nodes = gmsh.model.mesh.getElementsByType(2, s)[1]
        triangles.append(index[nodes.astype(np.int64)].reshape(-1, 3))
        surface.append(np.full(len(triangles[-1]), s))
    hits, which = checks.surface_crossings(points, np.concatenate(triangles))
    sides = tuple(max(phase_of.get(v, 0) for v in gmsh.model.getAdjacencies(2, int(s))[0])
                  for s in np.concatenate(surface)[which[:1].ravel()])
    return hits, sides


def _enclosed(phase_of: dict[int, int], yarns: int) -> np.ndarray:
    """Each yarn's volume [mm^3] enclosed by the current gmsh model's surface mesh (the tets gmsh
    fills a volume with hold exactly what its triangles enclose): checks.enclosed_volume of the
    boundary triangles of each of its pieces."""
    import gmsh

    points, index = model_nodes()
    out = np.zeros(yarns)
    for vol, ph in phase_of.items():
        if ph:
            faces = [index[gmsh.model.mesh.getElementsByType(2, f)[1].astype(np.int64)].reshape(-1, 3)
                     for _, f in gmsh.model.getBoundary([(3, vol)], combined=False, oriented=False)]
            out[ph - 1] += checks.enclosed_volume(points, faces)
    return out


def _fit_curvature(textile: Textile, options: TetOptions, phase_of: dict[int, int], model: np.ndarray) -> int:
    """Mesh the surfaces again with twice the elements per 2 pi of curvature, up to CURVATURE_STEPS
    times, while some yarn's surface mesh encloses more than SHORT below its model's volume
    (`model` [mm^3]): the triangles are chords of the yarn's curved surface, and lose most where
    a section's tip is sharp (the lenticular satin: 1.05 % short at 24 elements per 2 pi, 0.84 % at
    48; docs/tet_mesh.md). Returns the elements per 2 pi used."""
    import gmsh

    curvature, step = options.curvature, 0
    while True:
        short = 1 - _enclosed(phase_of, len(model)) / np.where(model > 0, model, np.inf)
        short[short > LOST / 100] = 0.0  # not the chords: OCC's cut lost it (the report fails the mesh)
        k = int(np.argmax(short))
        if short[k] <= SHORT or not curvature:
            return curvature
        if step == CURVATURE_STEPS:
            log.warning("tet: the surface mesh of %s encloses %.2f %% less than its model with %d elements per 2 pi of "
                        "curvature: a smaller --size meshes its surface finer", textile.yarns[k].name, 100 * short[k],
                        curvature)
            return curvature
        curvature, step = 2 * curvature, step + 1
        log.info("tet: the surface mesh of %s encloses %.2f %% less than its model: meshed again with %d elements "
                 "per 2 pi of curvature", textile.yarns[k].name, 100 * short[k], curvature)
        gmsh.model.mesh.clear()
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", curvature)
        mesh_surfaces()


def traced(textile: Textile, options: TetOptions, gap: float, shrink: float, height: float, times: dict,
           folder: str, move: np.ndarray, model: np.ndarray):
    """The surfaces meshed, with the box moved by `move` (_surfaces). When the surface mesh crosses
    itself (two skins that stray into the gap between them), the sections are traced again with
    twice the points, up to RETRACE times and while that halves the crossings. The surfaces are
    meshed finer where they lose a yarn's volume (_fit_curvature; `model`: each yarn's volume
    [mm^3]). Returns the box, pairs, volume tag -> phase, the move, how many times the points were
    doubled and the elements per 2 pi of curvature."""
    import gmsh

    before = np.inf
    for attempt in range(RETRACE + 1):
        # a retrace keeps the box where it went
        lo, hi, pairs, phase_of, move = _surfaces(textile, options, gap, shrink, height, times, folder, 2**attempt,
                                                  move)
        t = time.perf_counter()
        curvature = _fit_curvature(textile, options, phase_of, model)
        times["surfaces_s"] += time.perf_counter() - t
        hits, yarns = _crossings(phase_of)
        if not len(hits):
            break
        where = "(" + ", ".join(f"{v:.3f}" for v in hits[0]) + ") mm"
        names = " and ".join(textile.yarns[k - 1].name if k else "the box" for k in yarns)
        # no more tracing when it did not halve the crossings: the skins cross for another reason
        # (on TexGen's orthogonal weave: 1664, 1460 and 1360 crossings with 24, 48 and 96 points)
        if attempt == RETRACE or len(hits) > before / 2:
            raise MeshError(f"the tet mesh of {textile.name!r}: the skins of {names} cross at {where} "
                            f"({len(hits)} crossings in the surface mesh), "
                            f"with the sections traced by {2**attempt} x their points: solve with a larger "
                            "--min-gap, or use --kind voxel")
        log.warning("tet: the skins of %s cross at %s (%d crossings in the surface mesh): the sections traced again "
                    "with twice the points", names, where, len(hits))
        gmsh.model.remove()
        gmsh.model.add(f"tet-{textile.name}")
        before = len(hits)
    return lo, hi, pairs, phase_of, move, attempt, curvature


def skin_sections(textile: Textile, options: TetOptions, shrink: float) -> list[np.ndarray]:
    """Each yarn's section polygons over one period, as the skins are built (solids.yarn_sections)."""
    return [solids.yarn_sections(textile, i, options.spacing, options.points, shrink)
            for i in range(len(textile.yarns))]


def _surfaces(textile: Textile, options: TetOptions, gap: float, shrink: float, height: float, times: dict,
              folder: str, refine: int, move: np.ndarray):
    """The solids of the box (sections traced by refine x their points), their periodicity, sizes
    and surface mesh (the model current). The box is the cell's moved by `move` (mm), and moved
    again where OCC's cut loses a yarn or leaves faces on one side without their images on the
    other (sides.py). Returns the box, pairs, volume tag -> phase and the move."""
    import gmsh

    t = time.perf_counter()
    lo0, hi0 = box_corners(textile, options, gap, shrink)
    estimate = check_size(lo0, hi0, options)
    z_pad = None if options.z_range is not None else gap / 2
    sections = skin_sections(textile, options, shrink)
    legs = sides.legs_on_sides(textile, sections, lo0, hi0, options.spacing, gap)
    moves, tried = None, 0
    while True:
        lo, hi = lo0 + move, hi0 + move
        phase_of, lost = solids.build(textile, lo, hi, options.spacing, refine * options.points, shrink, z_pad,
                                      legs)
        if lost:
            names = ", ".join(textile.yarns[i].name for i in lost)
            why = f"OCC's cut of the skin of {names} by the box gave nothing"
        else:
            try:
                pairs = solids.periodic_pairs(lo, hi, (0, 1, 2), PAIR_TOLERANCE * float(np.max(hi - lo)))
                break
            except RuntimeError as e:  # a face cut on one side only (docs/tet_mesh.md)
                why = str(e)
        if moves is None:  # where the box may go instead (sides.moves), not where it is
            moves = [m for m in sides.moves(textile, sections, lo0, hi0) if not np.allclose(m, move)][:MOVES]
        if tried == len(moves):
            raise MeshError(f"the tet mesh of {textile.name!r}: {why}, with the box at the cell's origin and moved "
                            f"{tried} times along its sides; use --kind voxel")
        move, tried = moves[tried], tried + 1
        log.warning("tet: %s: the box moved by (%.4g, %.4g) mm along the cell's sides, into a gap between the yarns "
                    "along them", why, move[0], move[1])
        gmsh.model.remove()
        gmsh.model.add(f"tet-{textile.name}")
    times["solids_s"] = time.perf_counter() - t
    log.info("tet: %d yarn pieces and the matrix in the box %s - %s mm, %.1f s (about %d tets expected)",
             sum(1 for p in phase_of.values() if p), np.round(lo, 4).tolist(), np.round(hi, 4).tolist(),
             times["solids_s"], estimate)
    t = time.perf_counter()
    for _, slaves, masters, shift, _ in pairs:
        affine = np.eye(4)
        affine[:3, 3] = shift
        gmsh.model.mesh.setPeriodic(2, slaves, masters, affine.ravel().tolist())
    axes, h = size_grid(textile, lo, hi, options, gap, shrink, height)
    background(axes, h, folder)
    times["sizes_s"] = time.perf_counter() - t
    log.info("tet: periodic faces %s, sizes on a %s grid (least %.4f mm), %.1f s",
             [len(p[1]) for p in pairs], "x".join(map(str, h.shape)), h.min(), times["sizes_s"])
    for name, value in (("Mesh.MeshSizeExtendFromBoundary", 0), ("Mesh.MeshSizeFromPoints", 0),
                        ("Mesh.MeshSizeFromCurvature", options.curvature), ("Mesh.MeshSizeMax", options.size),
                        ("Mesh.MeshSizeMin", smallest(options, gap, height)), ("Mesh.Algorithm", 6),
                        ("Mesh.Algorithm3D", 1),
                        ("Mesh.Optimize", 1)):
        gmsh.option.setNumber(name, value)
    t = time.perf_counter()
    mesh_surfaces()
    times["surfaces_s"] = time.perf_counter() - t
    log.info("tet: surface mesh %.1f s", times["surfaces_s"])
    return lo, hi, pairs, phase_of, move
