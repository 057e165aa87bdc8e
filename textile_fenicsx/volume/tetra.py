"""The conforming, periodic tet mesh of a unit cell: matrix and yarns (gmsh OpenCASCADE).

Policy for yarns in contact (docs/tet_mesh.md has the measurements behind it): the yarns of a
corrected model touch at zero gap, and two solids that touch over an area cannot be meshed with
tets of bounded quality (the matrix between them is a wedge of zero angle where they part). So the
mesher needs a gap of matrix between every two yarns, at least `TetOptions.gap` [mm] (default 5 %
of the thinnest yarn's height), which the solve holds (`textile-fenicsx solve --min-gap G`,
SolverOptions.min_gap: the exact contact method keeps every contact node's gap >= G with the
sections unchanged, so no yarn volume is lost). The gap sheets are meshed with elements fitted to
them: the size at a point is `grading` x (its distance to the nearest yarn + its distance to the
nearest other yarn), between `smallest` and `size`, on a grid given to gmsh as a background field.
A model whose yarns overlap (deeper than 1 % of the thinnest yarn's height) is refused, naming the
pair, the place and the depth; one whose yarns are closer than 0.75 x the gap is refused too,
pointing to `solve --min-gap`, unless `shrink` is asked for: the last resort, every section scaled
about its centreline by the factor that opens the gap, and the volume lost reported.

The box is the cell in x, y and the yarns' own z extent padded by gap / 2 above and below (a stack
of identical plies is then separated by the gap, like yarns), or `z_range` (a mould's). The mesh
is periodic in x, y and z: gmsh copies the mesh of each - face onto its + face (`setPeriodic`),
and the + face's nodes are then put exactly on their partners' images.

gmsh runs on rank 0 only; the arrays are returned there (None on the other ranks); an error is
raised on every rank.
"""

from __future__ import annotations

import logging
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from mpi4py import MPI
from scipy.spatial import cKDTree

from textile_fenicsx.common.errors import GeometryError, MeshError, TextileError, check_positive
from textile_fenicsx.common.parallel import wait_asleep
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume import tetra_checks as checks
from textile_fenicsx.volume import tetra_sides
from textile_fenicsx.volume import tetra_solids as solids
from textile_fenicsx.volume.box import DEFAULT_SIZE, Box, periodic_mismatch

log = logging.getLogger(__name__)

# Overlap the mesher accepts, as a fraction of the thinnest yarn's height (the solve's check: verify.py).
OVERLAP_TOLERANCE = 0.01
# The least gap the mesher accepts, as a fraction of the gap asked for: the solve holds the gap at
# its nodes, and between them the gap dips by the P2 field's error (to 0.91 G on the lenticular satin).
ACCEPT = 0.75
# Memory of the mesh process per tet [bytes] and tets per mm^3 of box at size h, x h^3: measured on
# the corrected satin4 at size 0.25 (peak 1.4 GB and 300 756 tets in 127 mm^3: 4.7 kB and 37).
BYTES_PER_TET = 5e3
TETS_PER_VOLUME = 37.0
# gmsh's optimisers run on the volume mesh after its own (Mesh.Optimize 1, inside generate).
# Without that first pass the satin's mesh took 3 s less of 13 for the same quality (minSICN
# 0.014), but over the family the worst tet got worse (ours_orthogonal's minSICN 0.0023 instead of
# 0.0118, basket3's 0.0050 instead of 0.0098): kept.
OPTIMISE = ("Relocate3D", "")
# A tet whose volume is at most this fraction of the box's is flat: the mesh is refused
FLAT = 1e-12
# The size, as a fraction of the one asked for, a mesh with flat tets inside the box is made again
# at, once. gmsh's optimisers (and Relocate3D again) leave a flat tet whose four nodes all lie on a
# yarn's surface: binder1.375's gapped corrected model at 0.35 mm, two in the matrix (1.1e-10 mm^3)
# with two nodes on a seam of a binder's skin and two on the face beside it; at 0.3 mm none.
FLAT_RETRY = 0.85
# How far apart [fraction of the box] the bounding boxes of two faces paired as periodic may be: OCC's
# boxes of spline faces are loose (the faces are then checked by the mesh's periodicity).
PAIR_TOLERANCE = 5e-4
# A yarn whose meshed volume is off the model's by more than this [%] fails the mesh (OCC's cut of
# a skin by the box can give nothing, and no error: the binders of TexGen's orthogonal weave with
# their stations beside the box's sides kept; the sweep's worst otherwise is 2.5 %).
LOST = 10.0
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
# nothing or leaves the faces of two sides unpaired (tetra_sides.moves)
MOVES = 3


@dataclass(frozen=True)
class TetOptions:
    """Tet-mesh settings (lengths in mm).

    size: largest element size. gap: the least gap between yarns (and between a yarn and the box's
    top or bottom face, with gap / 2 there) the mesh is made for; default 5 % of the thinnest yarn's
    height. grading: element size per unit of local gap (the sum of the distances to the two
    nearest yarns). curvature: elements per 2 pi of the yarn surfaces' curvature (doubled, up to
    twice, where a yarn's surface mesh encloses more than SHORT less than its surface). spacing:
    station spacing along the yarns (at least one per master node, and 10 degrees of the path's
    turning at most: tetra_solids.TURN); points: points per section, spaced evenly along its
    perimeter (the spline through 24 of them undershoots the tips of the 3D weaves'
    thin flat sections: each yarn's solid 0.75 % short, every yarn -0.94..-1.05 % after meshing on
    l2l_w2f3_b3_0011; with 48, -0.35..-0.71 %; docs/tet_mesh.md). z_range:
    the box's (zmin, zmax), default the yarns' extent padded by gap / 2. shrink: allow the last
    resort (sections scaled down to open the gap; the volume lost is reported). max_elements:
    refuse a size estimated to give more tets. threads: gmsh's threads (at most 2 here).
    """

    size: float = DEFAULT_SIZE["tet"]
    gap: float | None = None
    grading: float = 3.0
    curvature: int = 24
    spacing: float = 0.25
    points: int = 48
    z_range: tuple | None = None
    shrink: bool = False
    max_elements: int = 3_000_000
    threads: int = 2
    memory_limit: float | None = None

    def __post_init__(self):
        check_positive("tet size", self.size)
        if self.gap is not None:
            check_positive("tet gap", self.gap)
        check_positive("tet grading", self.grading)
        check_positive("tet spacing", self.spacing)
        if int(self.points) < 8:
            raise TextileError(f"tet points per section must be >= 8, got {self.points!r}")
        if self.z_range is not None and not float(self.z_range[1]) > float(self.z_range[0]):
            raise TextileError(f"tet z_range must be (zmin, zmax) with zmax > zmin, got {self.z_range!r}")


@dataclass
class TetMesh:
    """Linear tets of the cell (on rank 0).

    points (N, 3) [mm]; tets (E, 4) node indices, positive orientation; phase (E,) 0 the matrix,
    1 + i yarn i; fibre (E, 3) unit fibre direction of yarn elements (0 in the matrix); lo, hi the
    box's corners [mm]; names: phase -> name; report: the mesh report (JSON-ready).
    """

    points: np.ndarray
    tets: np.ndarray
    phase: np.ndarray
    fibre: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    names: list
    report: dict = field(default_factory=dict)


def smallest(options: TetOptions, gap: float, height: float) -> float:
    """The smallest element size [mm]: half the gap, else a sixth of the largest size but no more
    than an eighth of the thinnest yarn's height (the curvature of a lens or ellipse tip would ask
    for elements of a hundredth of a mm all along every yarn's edges: 4x the tets on the plain
    weave for 0.3 % of its volume; coarser, the tips' chords lose more than 1 % of it)."""
    return max(gap / 2, min(options.size / 6, height / 8))


def thinnest_height(textile: Textile) -> float:
    """The least section height of any yarn [mm] (up extent of its section polygons)."""
    least = np.inf
    for y in textile.yarns:
        sec = y.section_points(y.stations(textile.resolution.spacing, 1), 32)
        least = min(least, float((sec[..., 1].max(axis=1) - sec[..., 1].min(axis=1)).min()))
    return least


def default_gap(textile: Textile, options: TetOptions) -> float:
    """The gap the mesh is made for [mm]: options.gap, else 5 % of the thinnest yarn's height."""
    return options.gap if options.gap is not None else 0.05 * thinnest_height(textile)


def check_contacts(textile: Textile, gap: float, shrink: bool, n: int = 200) -> dict:
    """The policy's check before meshing: refuse overlapping yarns; yarns closer than `gap` are
    refused too, or (shrink) get the section scale that opens it. Returns the measured gap, the
    pair, the place and the shrink fraction (0: none)."""
    height = thinnest_height(textile)
    g = checks.yarn_gaps(textile, n)
    info = {"least_gap_mm": g["gap"], "pair": g["pair"], "at_mm": g["at"], "thinnest_height_mm": height,
            "shrink": 0.0}
    if g["pair"] is None:
        return info
    a, b = (textile.yarns[k].name for k in g["pair"])
    where = "(" + ", ".join(f"{v:.3f}" for v in g["at"]) + ") mm"
    if g["gap"] < -OVERLAP_TOLERANCE * height:
        raise GeometryError(f"{a} and {b} overlap at {where}, {-g['gap']:.4f} mm deep (more than "
                            f"{OVERLAP_TOLERANCE:.0%} of the thinnest yarn's height, {height:.3f} mm): a tet mesh "
                            "needs yarns apart; correct the model with `textile-fenicsx solve --min-gap G` "
                            "first, or mesh it with --kind voxel")
    if g["gap"] < ACCEPT * gap:
        if not shrink:
            raise GeometryError(f"{a} and {b} are {g['gap']:.4f} mm apart at {where}, less than the gap the tet "
                                f"mesh needs ({gap:.4f} mm): solve with `textile-fenicsx solve --min-gap {gap:.3g}`, "
                                "or allow shrinking the sections (the volume lost is reported), or use --kind voxel")
        # sections scaled by (1 - s) move each surface by about s x its half height: open the gap
        info["shrink"] = float(min(0.5, (gap - g["gap"]) / height))
        log.warning("tet: %s and %s are %.4f mm apart at %s: sections shrunk by %.2f %% to open a %.4f mm gap",
                    a, b, g["gap"], where, 100 * info["shrink"], gap)
    return info


def _box(textile: Textile, options: TetOptions, gap: float, shrink: float) -> tuple[np.ndarray, np.ndarray]:
    c = textile.cell
    if options.z_range is not None:
        z0, z1 = map(float, options.z_range)
    else:
        z0, z1 = np.inf, -np.inf
        for i in range(len(textile.yarns)):  # sampled finer than the splines' points: they overshoot
            sec = solids.yarn_sections(textile, i, options.spacing / 2, 4 * options.points, shrink)
            z0, z1 = min(z0, sec[..., 2].min()), max(z1, sec[..., 2].max())
        z0, z1 = z0 - gap / 2, z1 + gap / 2
    return np.array([c.x0, c.y0, z0]), np.array([c.x0 + c.lx, c.y0 + c.ly, z1])


def check_size(lo: np.ndarray, hi: np.ndarray, options: TetOptions) -> int:
    """Refuse, before meshing, a size estimated to give more than max_elements tets or to need more
    memory than the limit (memory.check; default: what the system has available). Returns the
    estimate."""
    from textile_fenicsx.common import memory

    estimate = int(TETS_PER_VOLUME * float(np.prod(hi - lo)) / options.size**3)
    if estimate > options.max_elements:
        raise TextileError(f"tet size {options.size:g} mm would give about {estimate:.3g} tets, more than the limit "
                           f"of {options.max_elements:.3g}; use a larger size")
    memory.check(estimate * BYTES_PER_TET, what=f"tet size {options.size:g} mm would give about {estimate:.3g} "
                 "tets and", hint="use a larger size", limit_gb=options.memory_limit)
    return estimate


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


def _background(axes: list[np.ndarray], h: np.ndarray, folder: str) -> None:
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


def mesh_surfaces() -> None:
    """gmsh's surface mesh of the model. The Structured size field (_background) reads its file at
    its first use, unguarded: two threads meshing curves at once both read it, and one frees what
    the other reads (a segfault in gmsh 4.13). So the curves are meshed on one thread, which reads
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


def _nodes() -> tuple[np.ndarray, np.ndarray]:
    """The current gmsh model's nodes (N, 3) and the row of each node tag (-1: no such tag)."""
    import gmsh

    tags, xyz, _ = gmsh.model.mesh.getNodes()
    index = np.full(int(tags.max()) + 1, -1, np.int64)
    index[tags.astype(np.int64)] = np.arange(len(tags))
    return xyz.reshape(-1, 3), index


def _mesh_arrays(phase_of: dict[int, int], pairs: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """Nodes (N, 3), tets (E, 4) and phases (E,) of the current gmsh model, positively oriented,
    and per periodic axis of `pairs` the rows of the nodes gmsh put on the box's + and - faces."""
    import gmsh

    points, index = _nodes()
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


def _crossings(phase_of: dict[int, int]) -> tuple[np.ndarray, tuple[int, ...]]:
    """Where the current gmsh model's surface triangles cross (tetra_checks.surface_crossings),
    and the phases of the first two crossing triangles (the yarn each bounds, 0 the box)."""
    import gmsh

    points, index = _nodes()
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
    fills a volume with hold exactly what its triangles enclose): tetra_checks.enclosed_volume of
    the boundary triangles of each of its pieces."""
    import gmsh

    points, index = _nodes()
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


def _generate(textile: Textile, options: TetOptions, gap: float, shrink: float, height: float, times: dict,
              folder: str):
    """Build, mesh and read back the model (gmsh initialised, a model current): the surfaces
    (_traced), then the volume. Where gmsh's volume mesh fails on facets of a side of the box
    across x or y, the box moves once along that axis, its sides there farthest from the edges of
    the yarns running along them (tetra_sides.clear_of_edges), and the model is built again.
    Returns the arrays, box, pairs, how many times the points were doubled and the elements per
    2 pi of curvature."""
    import gmsh

    model = model_volumes(textile) * (1 - shrink) ** 2
    lo, hi, pairs, phase_of, move, attempt, curvature = _traced(textile, options, gap, shrink, height, times, folder,
                                                                np.zeros(3), model)
    t = time.perf_counter()
    try:
        gmsh.model.mesh.generate(3)
    except Exception as e:
        tol = PAIR_TOLERANCE * float(np.max(hi - lo))
        axis = _side_of(str(e), lo, hi, tol)
        if axis is None:
            raise
        places = [d for d in tetra_sides.clear_of_edges(textile, _sections(textile, options, shrink), lo - move,
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
        lo, hi, pairs, phase_of, move, attempt, curvature = _traced(textile, options, gap, shrink, height, times,
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


def _traced(textile: Textile, options: TetOptions, gap: float, shrink: float, height: float, times: dict,
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


def _sections(textile: Textile, options: TetOptions, shrink: float) -> list[np.ndarray]:
    """Each yarn's section polygons over one period, as the skins are built (tetra_solids.yarn_sections)."""
    return [solids.yarn_sections(textile, i, options.spacing, options.points, shrink)
            for i in range(len(textile.yarns))]


def _surfaces(textile: Textile, options: TetOptions, gap: float, shrink: float, height: float, times: dict,
              folder: str, refine: int, move: np.ndarray):
    """The solids of the box (sections traced by refine x their points), their periodicity, sizes
    and surface mesh (the model current). The box is the cell's moved by `move` (mm), and moved
    again where OCC's cut loses a yarn or leaves faces on one side without their images on the
    other (tetra_sides). Returns the box, pairs, volume tag -> phase
    and the move."""
    import gmsh

    t = time.perf_counter()
    lo0, hi0 = _box(textile, options, gap, shrink)
    estimate = check_size(lo0, hi0, options)
    z_pad = None if options.z_range is not None else gap / 2
    sections = _sections(textile, options, shrink)
    legs = tetra_sides.legs_on_sides(textile, sections, lo0, hi0, options.spacing, gap)
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
        if moves is None:  # where the box may go instead (tetra_sides.moves), not where it is
            moves = [m for m in tetra_sides.moves(textile, sections, lo0, hi0) if not np.allclose(m, move)][:MOVES]
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
    _background(axes, h, folder)
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


def tet_mesh(textile: Textile, options: TetOptions = TetOptions(), comm: MPI.Comm = MPI.COMM_WORLD) -> TetMesh | None:
    """The cell's conforming periodic tet mesh (on rank 0; None on the other ranks). Raises the same
    TextileError on every rank if the model is refused or gmsh fails (never hangs)."""
    result: TetMesh | None = None
    error: Exception | None = None
    if comm.rank == 0:
        try:
            result = _flat_retried(textile, options)
        except (TextileError, MeshError) as e:
            error = e
        except Exception as e:  # gmsh's own errors, reported on every rank
            error = MeshError(f"gmsh could not make the tet mesh of {textile.name!r}: {e}; try another --size or "
                              "--gap, or --kind voxel")
    wait_asleep(comm)  # the other ranks leave rank 0's gmsh threads the cores
    error = comm.bcast(error, root=0)
    if error is not None:
        raise error
    return result


class FlatTets(GeometryError):
    """gmsh's mesh has flat tets; inside: none of them on a side of the box."""

    def __init__(self, message: str, inside: bool = False):
        super().__init__(message)
        self.inside = inside


def _flat_retried(textile: Textile, options: TetOptions) -> TetMesh:
    """_tet_mesh; where gmsh's mesh has flat tets inside the box, made once more at FLAT_RETRY x
    the size (the report's size_mm is the one used)."""
    try:
        return _tet_mesh(textile, options)
    except FlatTets as e:
        if not e.inside:
            raise
        smaller = replace(options, size=FLAT_RETRY * options.size)
        log.warning("tet: %s: meshed again at size %.4g mm", str(e).split(";")[0], smaller.size)
        try:
            return _tet_mesh(textile, smaller)
        except FlatTets as again:
            raise FlatTets(f"{again} (at size {smaller.size:.4g} mm, and at {options.size:.4g} mm before)") from None


def session(options: TetOptions) -> None:
    """gmsh's options for a tet mesh that hold for its whole session."""
    import gmsh

    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", min(int(options.threads), 2))
    gmsh.option.setNumber("Geometry.OCCParallel", 1)


def _tet_mesh(textile: Textile, options: TetOptions) -> TetMesh:
    import gmsh

    start = time.perf_counter()
    if not textile.cell.periodic:
        raise TextileError(f"{textile.name!r}: a tet mesh is made of a periodic cell; this one has free edges")
    height = thinnest_height(textile)
    gap = default_gap(textile, options)
    contact = check_contacts(textile, gap, options.shrink)
    shrink = contact["shrink"]
    times: dict[str, float] = {}
    initialised = gmsh.isInitialized()
    if not initialised:
        gmsh.initialize(interruptible=False)
    added = False
    try:
        session(options)
        gmsh.model.add(f"tet-{textile.name}")
        added = True
        with tempfile.TemporaryDirectory(prefix="tet-sizes-") as folder:
            arrays, lo, hi, pairs, traced, curvature = _generate(textile, options, gap, shrink, height, times, folder)
        points, tets, phase, faces = arrays
        elements = gmsh.model.mesh.getElementsByType(4)[0]
        quality = gmsh.model.mesh.getElementQualities(elements, "minSICN")
        gamma = gmsh.model.mesh.getElementQualities(elements, "gamma")
    finally:
        if added:
            gmsh.model.remove()
        if not initialised:
            gmsh.finalize()
    t = time.perf_counter()
    snapped = _snap_periodic(points, lo, hi, faces)
    vol = checks.signed_volumes(points, tets)
    flip = vol < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    vol = np.abs(vol)
    _refuse_flat(textile.name, points, tets, vol, lo, hi)
    fibre = np.zeros((len(tets), 3))
    centroids = points[tets].mean(axis=1)
    for i in range(len(textile.yarns)):
        k = phase == i + 1
        if np.any(k):
            fibre[k] = textile.fibre_direction(i, centroids[k])
    mesh = TetMesh(points, tets, phase, fibre, lo, hi, ["matrix"] + [y.name for y in textile.yarns])
    mesh.report = _report(textile, mesh, vol, quality, gamma, contact, gap, options, times, pairs, flip)
    mesh.report["sections_retraced"] = traced
    mesh.report["curvature_per_2pi"] = curvature
    mesh.report["box_moved_mm"] = [float(lo[0] - textile.cell.x0), float(lo[1] - textile.cell.y0)]
    mesh.report["periodicity"]["snapped_mm"] = snapped
    times["checks_s"] = time.perf_counter() - t
    mesh.report["times_s"] = {**times, "total": time.perf_counter() - start}
    r = mesh.report
    lost = max(r["volume"]["per_yarn"], key=lambda y: abs(y["error_percent"]), default=None)
    if lost is not None and abs(lost["error_percent"]) > LOST:
        raise MeshError(f"the tet mesh of {textile.name!r} holds {lost['meshed_mm3']:.4g} mm^3 of {lost['yarn']} "
                        f"where the model has {lost['model_mm3']:.4g} ({lost['error_percent']:+.1f} %): OCC's cut "
                        "of its skin by the box lost it; use --kind voxel")
    log.info("tet: %d tets, %d nodes, quality (minSICN) min %.3f mean %.3f, yarn volume error worst %.2f %%, "
             "periodic %s, %.1f s", r["elements"], r["nodes"], r["quality"]["min"], r["quality"]["mean"],
             r["volume"]["worst_error_percent"], r["periodicity"]["periodic"], r["times_s"]["total"])
    return mesh


def _refuse_flat(name: str, points: np.ndarray, tets: np.ndarray, vol: np.ndarray, lo: np.ndarray,
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


def _snap_periodic(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, faces: list) -> float:
    """Put every node of a + face exactly on the image of its - face partner (gmsh places the
    copies it makes on the + face's own geometry, which OCC cut to about 1e-7 mm of the - face's
    moved). faces: per axis, the rows of the nodes gmsh put on its + and - faces (_mesh_arrays);
    only those move. A node near a face but not on it is a yarn's: where a side cuts a leg
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


# section points of the reference volumes: an analytic section's inscribed polygon of 64 points
# holds 0.15 % less than the section (satin4's ellipses), of 512 points 0.01 %
REFERENCE_POINTS = 512


def model_volumes(textile: Textile) -> np.ndarray:
    """Each yarn's volume in the cell [mm^3]: the volume its own surface encloses over its master
    nodes (verify.tube, the divergence theorem, on its sections traced with REFERENCE_POINTS).
    Every yarn lies whole in the box, and a periodic yarn's nodes span one period, which the
    periodic box holds once. The model's vertical rays (metrics, on the 64-point surfaces) converge
    to that surface's volume, at first order where legs are vertical: on the corrected
    ortho_w3f4's binders 400 rays a side read +0.44 %, 800 +0.21 % (docs/tet_mesh.md)."""
    from textile_fenicsx.correction.verify import tube

    fine = replace(textile.resolution, section_points=max(textile.resolution.section_points, REFERENCE_POINTS))
    return np.array([tube(y, fine).volume for y in textile.yarns])


def ray_volumes(textile: Textile, n: int = 400) -> np.ndarray:
    """Each yarn's volume in the cell [mm^3], by the model's vertical rays on an n x n grid."""
    from textile_fenicsx.model.metrics import measure

    return np.array(measure(textile, n=n)["yarn_volume"]["per_yarn"])


def _report(textile, mesh, vol, quality, gamma, contact, gap, options, times, pairs, flipped) -> dict:
    names = mesh.names
    meshed = np.bincount(mesh.phase, weights=vol, minlength=len(names))
    # the model's volumes: of the shrunk sections when the last resort was used
    model, rays = model_volumes(textile), ray_volumes(textile)
    apart = np.abs(rays / np.where(model > 0, model, np.inf) - 1)
    if len(apart) and apart.max() > 0.01:
        k = int(np.argmax(apart))
        log.warning("tet mesh: %s's surface encloses %.4g mm^3 and the model's rays read %.4g: the yarn's volume in "
                    "the cell is uncertain by %.1f %% (its meshed volume is compared with the surface's)",
                    names[1 + k], model[k], rays[k], 100 * apart[k])
    scale = (1 - contact["shrink"]) ** 2
    errors = (meshed[1:] - model * scale) / (model * scale) * 100
    angles = checks.fibre_angles(textile, mesh.points, mesh.tets, mesh.phase, mesh.fibre)
    return {
        "kind": "tet",
        "elements": int(len(mesh.tets)),
        "nodes": int(len(mesh.points)),
        "box_mm": {"lo": mesh.lo.tolist(), "hi": mesh.hi.tolist()},
        "size_mm": options.size,
        "quality": {"measure": "minSICN", "min": float(quality.min()), "mean": float(quality.mean()),
                    "below_0.1": int(np.sum(quality < 0.1)), "gamma_min": float(gamma.min()),
                    "gamma_mean": float(gamma.mean())},
        "inverted_by_gmsh": int(flipped.sum()),
        "smallest_volume_mm3": float(vol.min()),
        "policy": {"name": "gap" if not contact["shrink"] else "shrink",
                   "gap_mm": gap, "least_gap_in_model_mm": contact["least_gap_mm"],
                   "closest_pair": [names[1 + k] for k in contact["pair"]] if contact["pair"] else None,
                   "closest_at_mm": contact["at_mm"], "thinnest_height_mm": contact["thinnest_height_mm"],
                   "shrink_fraction": contact["shrink"],
                   "volume_lost_percent": float(100 * (1 - scale)) if contact["shrink"] else 0.0},
        "volume": {"per_yarn": [{"yarn": names[1 + i], "meshed_mm3": float(meshed[1 + i]), "model_mm3": float(model[i]),
                                 "model_rays_mm3": float(rays[i]), "error_percent": float(errors[i])}
                                for i in range(len(model))],
                   "matrix_mm3": float(meshed[0]), "box_mm3": float(np.prod(mesh.hi - mesh.lo)),
                   "worst_error_percent": float(np.max(np.abs(errors))) if len(errors) else 0.0},
        "fibre_angle_deg": {"p99": float(np.percentile(angles, 99)) if len(angles) else 0.0,
                            "max": float(angles.max()) if len(angles) else 0.0,
                            "within_2deg": float(np.mean(angles <= 2.0)) if len(angles) else 1.0},
        "phases": checks.phase_mismatch(textile, mesh.points, mesh.tets, mesh.phase),
        "periodicity": {**periodic_mismatch(mesh.points, Box(tuple(mesh.lo), tuple(mesh.hi))),
                        "face_pairs": {"xyz"[p[0]]: len(p[1]) for p in pairs}},
    }
