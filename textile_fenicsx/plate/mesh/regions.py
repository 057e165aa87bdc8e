"""The gmsh model of the projected regions (DESIGN.md section 4, step 2), on one rank.

gmsh OCC fragments the cell by all footprints into basic regions, each covered by a fixed set of
yarns (one physical group per set), with periodic opposite sides (periodic_sides.py) and element
size = seed; nearly coincident yarn edges are merged by OCC's boolean tolerance instead of leaving
slivers, and narrow regions get smaller elements; a flat triangle left at the tip of a wedge
between two edges that part at a tiny angle is flipped with its neighbour (caps.py). The result is
plain arrays: node coordinates, triangles, each triangle's covering set, and the mesh's statistics.
"""

import logging
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from textile_fenicsx.common.errors import GeometryError
from textile_fenicsx.common.interrupts import time_limit
from textile_fenicsx.model.textile import Cell
from textile_fenicsx.plate.mesh.caps import CAP_ANGLE, flip_caps, triangle_angles
from textile_fenicsx.plate.mesh.periodic_sides import box_with_marks, outlines_on_sides, periodic_sides, side_marks

__all__ = ["GROWTH", "LIMIT_PER_TRIANGLE_S", "LIMIT_S", "fresh_start", "gmsh_session", "region_mesh", "session_options",
           "time_limit_s"]

log = logging.getLogger(__name__)

# How fast element size may grow away from narrow regions (size change per unit distance).
GROWTH = 1.0
# A try of region_mesh that has not ended after LIMIT_S + LIMIT_PER_TRIANGLE_S per triangle of the
# seed's size over the cell [s] is not going to: gmsh 4.13's initial 2D Delaunay (GFaceInitialMesh)
# looped for over 20 minutes on TexGen's refined orthogonal weave moved 0.7 mm in the plane, a model
# whose tries otherwise end in seconds. Generous: a million triangles get 2 300 s.
LIMIT_S = 300.0
LIMIT_PER_TRIANGLE_S = 2e-3


@contextmanager
def gmsh_session(owner: bool) -> Iterator[None]:
    """gmsh initialised (unless it already was) with the settings of the projected mesh; on leaving,
    the model removed on the rank that built it (`owner`) and gmsh finalised if this opened it."""
    import gmsh

    initialised = gmsh.isInitialized()
    if not initialised:
        gmsh.initialize(interruptible=False)
    session_options()
    try:
        yield
    finally:
        if owner:
            gmsh.model.remove()
        if not initialised:
            gmsh.finalize()


def session_options() -> None:
    """gmsh's options for the projected mesh that hold for a whole session (region_mesh sets the
    others for each model)."""
    import gmsh

    gmsh.option.setNumber("General.Terminal", 0)
    # OpenCASCADE's booleans on threads: the same meshes to the last bit (satin4, plain, twill22,
    # our orthogonal weave), 15-20 % less time. Not gmsh's threaded 2D meshing: its meshes differ
    # from run to run.
    gmsh.option.setNumber("Geometry.OCCParallel", 1)


def fresh_start() -> None:
    """Everything gone from gmsh but the session (after a model it could not mesh): the models, and
    the options back to gmsh's defaults and the session's. Removing the model alone is not enough:
    after "Unable to recover the edge" the next model made in the same session meshed to no
    triangles at all (gmsh 4.13, TexGen's refined orthogonal weave), unless the options were
    restored."""
    import gmsh

    gmsh.clear()
    gmsh.option.restoreDefaults()
    session_options()


def region_mesh(cell: Cell, outlines: list, seed: float, sliver: float,
                name: str) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], dict, dict]:
    """Build and mesh the gmsh model `name` on this rank from the cell and each yarn's footprint
    outlines [(yarn, [(right, left), ...]), ...], element size `seed` [mm], edges closer than
    `sliver` [mm] merged; returns (mesh arrays (_mesh_arrays), coverage {tag: yarns}, stats).
    Under the command line, a try that runs past time_limit_s ends the run (interrupts.time_limit)."""
    limit = time_limit_s(cell, seed)

    def message() -> str:
        return (f"gmsh did not finish meshing the projected regions of {name} in {limit:.0f} s (a try takes "
                "seconds; gmsh's 2D Delaunay can loop where footprints nearly touch): try another --seed, "
                "or --sliver")

    with time_limit(limit, message):
        return _region_mesh(cell, outlines, seed, sliver, name)


def time_limit_s(cell: Cell, seed: float) -> float:
    """How long one try of region_mesh may take [s]: LIMIT_S, plus LIMIT_PER_TRIANGLE_S for each
    triangle the seed gives the cell (TexGen's refined orthogonal weave, 6 900 triangles at seed
    0.5 mm, 1 100 of them the seed's: 15-18 s; the satin 1 s)."""
    return LIMIT_S + LIMIT_PER_TRIANGLE_S * cell.lx * cell.ly / (np.sqrt(3) / 4 * seed**2)


def _region_mesh(cell: Cell, outlines: list, seed: float, sliver: float,
                 name: str) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], dict, dict]:
    import gmsh

    gmsh.model.add(name)
    gmsh.option.setNumber("Geometry.ToleranceBoolean", sliver)
    covering, coverage = _covering_regions(cell, outlines, sliver)
    if cell.periodic:
        periodic_sides(cell, sliver)
    _narrow_region_sizes(covering, seed, sliver)
    gmsh.option.setNumber("Mesh.MeshSizeMax", seed)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeMin", 0.0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.Algorithm", 6)  # Frontal-Delaunay: well-shaped triangles
    gmsh.option.setNumber("Mesh.Optimize", 1)
    gmsh.model.mesh.generate(2)
    x, cells, tags = _mesh_arrays()
    _no_triangle_twice(x, cells)
    cells, tags, flipped = flip_caps(x, cells, tags)
    if flipped:
        log.info("mesh: %d flat triangles (an angle under %g deg, corners on one line) flipped with their "
                 "neighbours (meshes/caps.py)", flipped, CAP_ANGLE)
    angles = triangle_angles(x[cells])
    return (x, cells, tags), coverage, {"nodes": int(len(x)), "triangles": int(len(cells)),
                                        "min_angle_deg": float(angles.min()),
                                        "fraction_below_20_deg": float(np.mean(angles.min(axis=1) < 20.0)),
                                        "regions": int(len(covering)), "sliver_tolerance_mm": sliver,
                                        "caps_flipped": flipped}


def _no_triangle_twice(x: np.ndarray, cells: np.ndarray) -> None:
    """Refuse (GeometryError, naming the place) a mesh with a triangle twice over the same three
    nodes: gmsh meshed two surfaces that overlap (TexGen's refined orthogonal weaves at seed 0.25:
    32-192 such triangles, and DOLFINx then stopped on "Duplicate mesh entity" or crashed in
    create_mesh; why gmsh made them there is not known)."""
    _, first, count = np.unique(np.sort(cells, axis=1), axis=0, return_index=True, return_counts=True)
    twice = first[count > 1]
    if len(twice):
        at = x[cells[twice[0]]].mean(axis=0)
        raise GeometryError(f"gmsh made {len(twice)} triangles twice over the same nodes (regions that overlap), "
                            f"the first at ({at[0]:.3f}, {at[1]:.3f}) mm; try another --seed")


def _covering_regions(cell: Cell, outlines: list, sliver: float) -> tuple[dict, dict]:
    """The cell fragmented by the footprints (synchronised), one physical group per covering set:
    ({surface tag: set of yarns over it}, {physical tag: sorted tuple of yarns})."""
    import gmsh

    occ = gmsh.model.occ
    x0, x1, y0, y1 = cell.bounds
    if cell.periodic:
        outlines = outlines_on_sides(outlines, cell, sliver)
        on_x, on_y = side_marks([np.vstack((r, l_[::-1], r[:1])) for _, sides in outlines for r, l_ in sides],
                                cell, sliver)
        box = box_with_marks(cell, on_x, on_y)
    else:
        box = occ.addRectangle(x0, y0, 0, cell.lx, cell.ly)
    pieces = []  # (yarn, surface tag) of each footprint piece inside the cell
    for i, sides in outlines:
        for right, left in sides:
            # Each side is one smooth spline through its chain: gmsh then places nodes by the seed.
            right, left = _distinct(right), _distinct(left)
            pr = [occ.addPoint(px, py, 0) for px, py in right]
            pl = [occ.addPoint(px, py, 0) for px, py in left[::-1]]
            loop = [occ.addSpline(pr), occ.addLine(pr[-1], pl[0]), occ.addSpline(pl), occ.addLine(pl[-1], pr[0])]
            surf = occ.addPlaneSurface([occ.addCurveLoop(loop)])
            clip = occ.addRectangle(x0, y0, 0, cell.lx, cell.ly)
            out, _ = occ.intersect([(2, surf)], [(2, clip)])
            pieces += [(i, tag) for dim, tag in out if dim == 2]
    if pieces:
        out, out_map = occ.fragment([(2, box)], [(2, t) for _, t in pieces])
    else:
        out, out_map = [(2, box)], [[(2, box)]]
    occ.synchronize()
    covering: dict[int, set[int]] = {tag: set() for dim, tag in out if dim == 2}
    for (yarn, _), children in zip(pieces, out_map[1:]):
        for dim, tag in children:
            if dim == 2:
                covering[tag].add(yarn)
    sets = sorted({tuple(sorted(s)) for s in covering.values()})
    coverage = {k + 1: s for k, s in enumerate(sets)}
    for k, s in coverage.items():
        surfaces = [t for t, c in covering.items() if tuple(sorted(c)) == s]
        gmsh.model.addPhysicalGroup(2, surfaces, k, name="yarns " + (" ".join(map(str, s)) or "none"))
    return covering, coverage


def _narrow_region_sizes(covering: dict, seed: float, sliver: float) -> None:
    """Narrow regions (gaps between yarns, strips along the cell sides; width ~ 2 area / perimeter)
    get elements twice their width: one row of well-shaped triangles across, no needles (gmsh's
    background size field)."""
    import gmsh

    occ = gmsh.model.occ
    sizes: dict[float, list[int]] = {}
    for tag in covering:
        area = occ.getMass(2, tag)
        perimeter = sum(occ.getMass(1, abs(c)) for _, c in gmsh.model.getBoundary([(2, tag)], oriented=False))
        h = min(seed, max(4 * area / perimeter, sliver, seed / 50))
        if h < seed:
            sizes.setdefault(round(h, 6), []).append(tag)
    fields = []
    for h, surfaces in sizes.items():
        # size h on the narrow regions' boundaries, growing by GROWTH per unit distance up to the seed
        curves = sorted({abs(c) for _, c in gmsh.model.getBoundary([(2, t) for t in surfaces], oriented=False)})
        dist = gmsh.model.mesh.field.add("Distance")
        gmsh.model.mesh.field.setNumbers(dist, "CurvesList", curves)
        gmsh.model.mesh.field.setNumber(dist, "Sampling", 200)
        f = gmsh.model.mesh.field.add("Threshold")
        gmsh.model.mesh.field.setNumber(f, "InField", dist)
        gmsh.model.mesh.field.setNumber(f, "SizeMin", h)
        gmsh.model.mesh.field.setNumber(f, "SizeMax", seed)
        gmsh.model.mesh.field.setNumber(f, "DistMin", h / 2)
        gmsh.model.mesh.field.setNumber(f, "DistMax", h / 2 + (seed - h) / GROWTH)
        fields.append(f)
    if fields:
        smallest = gmsh.model.mesh.field.add("Min")
        gmsh.model.mesh.field.setNumbers(smallest, "FieldsList", fields)
        gmsh.model.mesh.field.setAsBackgroundMesh(smallest)


def _distinct(chain: np.ndarray) -> np.ndarray:
    """The chain without points that repeat the one before (snapping can make them)."""
    step = np.linalg.norm(np.diff(chain, axis=0), axis=1)
    return chain[np.r_[True, step > 1e-9]]


def _mesh_arrays() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The triangles of every physical group of the gmsh model: node coordinates (N, 2) of the used
    nodes only, cells (M, 3) indexing them, and each cell's physical tag (M,)."""
    import gmsh

    tags, xyz, _ = gmsh.model.mesh.getNodes()
    pieces, values = [], []
    for _, k in gmsh.model.getPhysicalGroups(2):
        for ent in gmsh.model.getEntitiesForPhysicalGroup(2, k):
            types, _, nodes = gmsh.model.mesh.getElements(2, ent)
            for etype, enodes in zip(types, nodes):
                if etype != 2:
                    raise GeometryError(f"gmsh produced elements of type {etype}, expected triangles")
                pieces.append(enodes.reshape(-1, 3))
                values.append(np.full(len(pieces[-1]), k, dtype=np.int32))
    cells = np.vstack(pieces).astype(np.int64)
    used, compact = np.unique(cells, return_inverse=True)
    position = np.empty(int(tags.max()) + 1, dtype=np.int64)
    position[tags.astype(np.int64)] = np.arange(len(tags))
    x = xyz.reshape(-1, 3)[position[used], :2]
    return x, compact.reshape(-1, 3), np.concatenate(values)
