"""The projected-region mesh of the unit cell (DESIGN.md section 4).

1. Footprint of each yarn: its outline seen along z, from the lateral extremes of its sections at
   stations a quarter of the seed apart, chained over neighbouring periods and clipped to the cell.
2. gmsh OCC fragments the cell by all footprints into basic regions, each covered by a fixed set of
   yarns (one physical group per set), with periodic opposite sides and element size = seed.
   Nearly coincident yarn edges are merged by OCC's boolean tolerance instead of leaving slivers.
3. The triangles go to DOLFINx from rank 0 (`create_mesh` with the used nodes only, cell tags by
   `distribute_entity_data`, as gmshio does), distributed with shared-facet ghosts (dS forms).
4. A ghost strip (copies of the cells along the left and bottom sides, beyond the right and top
   sides) gives the periodic seam facets their second neighbour (DESIGN.md sections 6, 11).
A coupon made by `coupon.tile` is not meshed by gmsh as a whole: its unit cell is, and the unit
cell's triangles are repeated nx x ny times (the periodic sides match node for node), each cell
going to the copy of its yarns whose centreline is nearest. Every repeat then has the same mesh,
and a periodic coupon's solution repeats the unit cell's to round-off.
"""

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
from mpi4py import MPI
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

import dolfinx
from textile_fenicsx import limits
from textile_fenicsx.errors import GeometryError, TextileError
from textile_fenicsx.textile import Textile

log = logging.getLogger(__name__)

# How fast element size may grow away from narrow regions (size change per unit distance).
GROWTH = 1.0
# Cell tags of the ghost strip: a copy of region k's cells beyond the right/top sides has tag k + GHOST.
GHOST = 10_000_000


@dataclass(frozen=True)
class MeshOptions:
    """Projected-mesh settings.

    seed: target element size [mm]. sliver: edges of different yarns closer than this [mm] are merged
    (default seed / 20). max_slope: steepest centreline slope |dz| / |dxy| the method accepts; above
    it the through-thickness part of a yarn is narrower in plan than a tenth of its rise and cannot
    be a plate (default 10, i.e. 84 degrees). allow_steep: warn instead of stopping.
    memory_limit: largest memory [GB] a run may need (estimated from the seed before meshing; default
    the memory the system has available); a finer seed is refused, saying how much it would need.
    """

    seed: float = 0.5
    sliver: float | None = None
    max_slope: float = 10.0
    allow_steep: bool = False
    memory_limit: float | None = None

    def __post_init__(self):
        if not (np.isfinite(self.seed) and self.seed > 0):
            raise TextileError(f"mesh seed must be a positive size in mm, got {self.seed!r}")
        limits.check_length("mesh seed", self.seed)
        if self.sliver is not None and not (np.isfinite(self.sliver) and self.sliver >= 0):
            raise TextileError(f"sliver tolerance must be >= 0 mm, got {self.sliver!r}")
        if self.sliver is not None:
            limits.check_range("sliver tolerance", self.sliver, 0.0, limits.MAX_SIZE, " mm")
        if not self.max_slope > 0:
            raise TextileError(f"max_slope must be > 0, got {self.max_slope!r}")
        limits.check_range("max_slope", self.max_slope, 1e-6, limits.MAX_SLOPE)
        if self.memory_limit is not None and not (np.isfinite(self.memory_limit) and self.memory_limit > 0):
            raise TextileError(f"memory limit must be a positive size in GB, got {self.memory_limit!r}")
        if self.memory_limit is not None:
            limits.check_range("memory limit", self.memory_limit, 1e-6, limits.MAX_MEMORY_GB, " GB")


# Memory of a run per unknown, measured by `make bench` (satin coupons, summed peaks: 3.3e5 dofs on
# 1 and 2 ranks 5.8 and 7.5 kB per dof, 1.3e6 dofs on 2 ranks 6.9 kB per dof, with MUMPS' factors
# and the outputs), and per process.
BYTES_PER_DOF = 8e3
# the same with MUMPS' factors on disk (SolverOptions.out_of_core)
BYTES_PER_DOF_OUT_OF_CORE = 6e3
BYTES_PER_RANK = 0.3e9


def available_memory() -> float:
    """Memory the system can give [bytes] (Linux MemAvailable; inf where unknown)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    return float("inf")


def estimated_dofs(textile: Textile, seed: float, repeats: tuple[int, int] = (1, 1)) -> int:
    """Unknowns a seed will give, from the footprint areas: about 2.3 triangles per seed^2 and 2 P2
    dofs per triangle (within -20 % on the satin; gaps between yarns add cells this ignores). A
    coupon (made by coupon.tile, or to be made with `repeats`) is estimated from its unit cell
    times the number of repeats, which takes the same time (well under a second) for any coupon."""
    tiling = getattr(textile, "tiling", None)
    if tiling is not None:
        textile, repeats = tiling.unit, (tiling.nx * repeats[0], tiling.ny * repeats[1])
    spacing = max(0.1, 0.01 * max(textile.cell.lx, textile.cell.ly))  # about 100 stations per cell
    area = sum(footprint_area(textile, i, spacing=spacing) for i in range(len(textile.yarns)))
    return int(4.6 * area * repeats[0] * repeats[1] / seed**2)


def check_memory(textile: Textile, options: "MeshOptions", ranks: int, repeats: tuple[int, int] = (1, 1),
                 bytes_per_dof: float = BYTES_PER_DOF) -> None:
    """Refuse, before meshing (and before tiling a coupon of `repeats` unit cells), a seed whose
    run would need more memory than the limit (bytes_per_dof: BYTES_PER_DOF, or
    BYTES_PER_DOF_OUT_OF_CORE for a solve with MUMPS' factors on disk)."""
    dofs = estimated_dofs(textile, options.seed, repeats)
    need = dofs * bytes_per_dof + ranks * BYTES_PER_RANK
    limit = available_memory() if options.memory_limit is None else options.memory_limit * 1e9
    if need > limit:
        which = "the memory limit you gave" if options.memory_limit is not None else "the memory available now"
        tiling = getattr(textile, "tiling", None)
        nx, ny = (tiling.nx, tiling.ny) if tiling is not None else (1, 1)
        nx, ny = nx * repeats[0], ny * repeats[1]
        coupon = f"a {nx} x {ny} coupon at " if (nx, ny) != (1, 1) else ""
        raise TextileError(f"{coupon}mesh seed {options.seed:g} mm would give about {dofs:.3g} unknowns and need "
                           f"about {need / 1e9:.1f} GB, more than {which} ({limit / 1e9:.1f} GB); use a larger seed"
                           f"{' or fewer repeats' if coupon else ''} (or --memory-limit if you know better)")


@dataclass
class ProjectedMesh:
    """The cell's triangle mesh with, per cell, the set of yarns covering it.

    mesh: dolfinx Mesh (P1 triangles, shared-facet ghosts). cell_tags: MeshTags of the region tag per
    cell. coverage: region tag -> tuple of yarn indices over it (empty tuple: no yarn).
    stats: counts and quality measured on rank 0 (JSON-ready).
    """

    mesh: dolfinx.mesh.Mesh
    cell_tags: dolfinx.mesh.MeshTags
    coverage: dict
    textile: Textile
    options: MeshOptions
    stats: dict = field(default_factory=dict)
    cell: object = None

    def yarn_cells(self, i: int, strip: bool = True) -> np.ndarray:
        """Local cells (owned and ghost) covered by yarn i, with its ghost-strip copies if `strip`."""
        tags = [t for t, s in self.coverage.items() if i in s]
        if strip:
            tags += [t + GHOST for t in tags]
        return np.sort(self.cell_tags.indices[np.isin(self.cell_tags.values, tags)])

    def real_cells(self) -> np.ndarray:
        """Local cells of the unit cell itself (not the ghost strip)."""
        return np.sort(self.cell_tags.indices[self.cell_tags.values < GHOST])


def check_slopes(textile: Textile, options: MeshOptions) -> list[str]:
    """Raise GeometryError naming yarn, place and slope where a centreline is steeper than allowed."""
    warnings = []
    for i, y in enumerate(textile.yarns):
        s = y.stations(options.seed / 8)
        pos, tan = y.centreline(s)
        slope = np.abs(tan[:, 2]) / np.maximum(np.linalg.norm(tan[:, :2], axis=1), 1e-300)
        k = int(np.argmax(slope))
        if slope[k] > options.max_slope:
            x, yy, z = pos[k]
            msg = (f"{y.name} (yarn {i}) is too steep for the projected-plate method at "
                   f"({x:.3f}, {yy:.3f}, {z:.3f}) mm: slope {slope[k]:.3g} (angle "
                   f"{np.degrees(np.arctan(slope[k])):.1f} deg) exceeds max_slope {options.max_slope:g}")
            if not options.allow_steep:
                raise GeometryError(msg + "; smooth the yarn path, or allow_steep to continue anyway")
            warnings.append(msg)
    return warnings


def footprint_outlines(textile: Textile, i: int, spacing: float, pad: float = 0.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Outlines of yarn i seen along z: one (right, left) pair of side chains ((n, 2) each, in the
    yarn's direction) per lateral copy that reaches the cell grown by `pad`, long enough to cover
    the cell along the yarn (several periods chained). The closed outline is right + reversed left."""
    yarn = textile.yarns[i]
    s = yarn.stations(spacing)
    pos, _, up, side = yarn.frames(s)
    sec = yarn.section_points(s, textile.resolution.section_points)
    pts = pos[:, None, :2] + sec[..., :1] * side[:, None, :2] + sec[..., 1:] * up[:, None, :2]
    # Lateral direction: the in-plane normal of the yarn's overall direction.
    axis = yarn.period[:2] if yarn.periodic else (yarn.nodes[-1] - yarn.nodes[0])[:2]
    axis = axis / np.linalg.norm(axis)
    normal = np.array([-axis[1], axis[0]])
    lateral = np.einsum("mkj,j->mk", pts - pos[:, None, :2], normal)
    m = np.arange(len(s))
    left, right = pts[m, np.argmax(lateral, axis=1)], pts[m, np.argmin(lateral, axis=1)]
    lo, hi = pts.reshape(-1, 2).min(axis=0), pts.reshape(-1, 2).max(axis=0)
    x0, x1, y0, y1 = textile.cell.bounds
    region = (x0 - pad, x1 + pad, y0 - pad, y1 + pad)
    if not yarn.periodic:  # a piece (free edges, or a crown of a cut yarn): its copies by the repeats
        return [(right + t[:2], left + t[:2]) for t in textile._translations(yarn, np.r_[lo, 0], np.r_[hi, 0], region)]
    P = yarn.period[:2]
    outlines = {}
    for t in textile._translations(yarn, np.r_[lo, 0], np.r_[hi, 0], region):
        k = int(np.round(t[:2] @ P / (P @ P)))
        b = t[:2] - k * P
        outlines.setdefault(tuple(np.round(b, 9)), (b, []))[1].append(k)
    result = []
    for b, ks in outlines.values():
        ks = range(min(ks) - 1, max(ks) + 2)
        R = np.concatenate([right[(1 if n else 0):] + k * P + b for n, k in enumerate(ks)])
        L = np.concatenate([left[(1 if n else 0):] + k * P + b for n, k in enumerate(ks)])
        result.append((R, L))
    return result


def snap_to_sides(points: np.ndarray, cell, tol: float) -> np.ndarray:
    """Footprint outline points within tol of a cell side line (or of one of its periodic copies)
    put onto it. gmsh's boolean tolerance (tol) would otherwise merge such a point onto the side
    on one side of the cell and leave its periodic copy beside the other (a binder's edge 0.0125 mm
    inside the top side: its copy lies outside the bottom side). Coordinates are compared modulo
    the cell, so every periodic copy of a point moves alike."""
    if not cell.periodic or tol <= 0:
        return points
    out = points.copy()
    for axis, lo, length in ((0, cell.bounds[0], cell.lx), (1, cell.bounds[2], cell.ly)):
        line = lo + np.round((out[:, axis] - lo) / length) * length
        near = np.abs(out[:, axis] - line) < tol
        out[near, axis] = line[near]
    return out


def side_marks(chains: list[np.ndarray], cell, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Where footprint outlines (polylines) meet the cell's sides, as coordinates along them: the
    y of every meeting with x = x0 + k lx and the x of every meeting with y = y0 + k ly, each
    wrapped into the cell. Both sides of a pair get a vertex at each, so that their curves pair
    one to one (gmsh's periodic meshing needs that, and a yarn edge that ends on one side need not
    end on the other)."""
    x0, x1, y0, y1 = cell.bounds
    marks = [[], []]
    for chain in chains:
        for axis, lo, length in ((0, x0, cell.lx), (1, y0, cell.ly)):
            other = 1 - axis
            rel = (chain[:, axis] - lo) / length
            k = np.round(rel)
            on = np.abs(rel - k) * length < 1e-9 * length
            marks[axis].append(chain[on, other])
            # crossings of a line between consecutive points
            a, b = chain[:-1], chain[1:]
            fa, fb = np.floor((a[:, axis] - lo) / length), np.floor((b[:, axis] - lo) / length)
            cross = (fa != fb) & ~on[:-1] & ~on[1:]
            if np.any(cross):
                line = lo + np.maximum(fa[cross], fb[cross]) * length
                t = (line - a[cross, axis]) / (b[cross, axis] - a[cross, axis])
                marks[axis].append(a[cross, other] + t * (b[cross, other] - a[cross, other]))
    out = []
    for axis, (lo, length) in enumerate(((y0, cell.ly), (x0, cell.lx))):
        v = np.concatenate(marks[axis]) if marks[axis] else np.zeros(0)
        v = lo + np.mod(v - lo, length)
        v = np.unique(np.round(v, 9))
        v = v[(v - lo > tol) & (lo + length - v > tol)]  # not at the corners
        if len(v) > 1:  # one vertex for marks closer than the tolerance
            v = v[np.r_[True, np.diff(v) > tol]]
        out.append(v)
    return out[0], out[1]


def _clip_to_box(poly: np.ndarray, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    """Sutherland-Hodgman: the part of polygon poly (n, 2) inside the box (convex clip window)."""
    for axis, value, keep_above in ((0, x0, True), (0, x1, False), (1, y0, True), (1, y1, False)):
        if len(poly) == 0:
            break
        inside = poly[:, axis] >= value if keep_above else poly[:, axis] <= value
        nxt = np.roll(poly, -1, axis=0)
        nxt_in = np.roll(inside, -1)
        out = []
        for p, q, pin, qin in zip(poly, nxt, inside, nxt_in):
            if pin:
                out.append(p)
            if pin != qin:
                f = (value - p[axis]) / (q[axis] - p[axis])
                out.append(p + f * (q - p))
        poly = np.array(out).reshape(-1, 2)
    return poly


def footprint_area(textile: Textile, i: int, spacing: float = 0.02) -> float:
    """Area [mm^2] of yarn i seen along z within the cell, from its section extremes at stations
    `spacing` apart (independent of any mesh)."""
    area = 0.0
    for right, left in footprint_outlines(textile, i, spacing):
        clipped = _clip_to_box(np.vstack((right, left[::-1])), *textile.cell.bounds)
        if len(clipped) >= 3:
            x, y = clipped[:, 0], clipped[:, 1]
            area += 0.5 * abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return float(area)


def _gmsh_model(cell, outlines: list, options: MeshOptions, comm_self_name: str):
    """Build and mesh the gmsh model on this rank from the cell and each yarn's footprint outlines
    [(yarn, [(right, left), ...]), ...]; returns (mesh arrays, coverage, stats)."""
    import gmsh

    occ = gmsh.model.occ
    x0, x1, y0, y1 = cell.bounds
    sliver = options.seed / 20 if options.sliver is None else options.sliver
    gmsh.model.add(comm_self_name)
    gmsh.option.setNumber("Geometry.ToleranceBoolean", sliver)
    if cell.periodic:
        outlines = [(i, [(snap_to_sides(r, cell, sliver), snap_to_sides(l_, cell, sliver)) for r, l_ in sides])
                    for i, sides in outlines]
        on_x, on_y = side_marks([np.vstack((r, l_[::-1], r[:1])) for _, sides in outlines for r, l_ in sides],
                                cell, sliver)
        box = _box_with_marks(cell, on_x, on_y)
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
    covering = {tag: set() for dim, tag in out if dim == 2}
    for (yarn, _), children in zip(pieces, out_map[1:]):
        for dim, tag in children:
            if dim == 2:
                covering[tag].add(yarn)
    sets = sorted({tuple(sorted(s)) for s in covering.values()})
    coverage = {k + 1: s for k, s in enumerate(sets)}
    tag_of = {s: k for k, s in coverage.items()}
    for k, s in coverage.items():
        surfaces = [t for t, c in covering.items() if tuple(sorted(c)) == s]
        gmsh.model.addPhysicalGroup(2, surfaces, k, name="yarns " + (" ".join(map(str, s)) or "none"))

    if cell.periodic:
        _periodic_sides(cell, sliver)


    # Narrow regions (gaps between yarns, strips along the cell sides; width ~ 2 area / perimeter) get
    # elements twice their width: one row of well-shaped triangles across, no needles.
    sizes = {}
    for tag in covering:
        area = occ.getMass(2, tag)
        perimeter = sum(occ.getMass(1, abs(c)) for _, c in gmsh.model.getBoundary([(2, tag)], oriented=False))
        h = min(options.seed, max(4 * area / perimeter, sliver, options.seed / 50))
        if h < options.seed:
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
        gmsh.model.mesh.field.setNumber(f, "SizeMax", options.seed)
        gmsh.model.mesh.field.setNumber(f, "DistMin", h / 2)
        gmsh.model.mesh.field.setNumber(f, "DistMax", h / 2 + (options.seed - h) / GROWTH)
        fields.append(f)
    if fields:
        smallest = gmsh.model.mesh.field.add("Min")
        gmsh.model.mesh.field.setNumbers(smallest, "FieldsList", fields)
        gmsh.model.mesh.field.setAsBackgroundMesh(smallest)
    gmsh.option.setNumber("Mesh.MeshSizeMax", options.seed)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeMin", 0.0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.Algorithm", 6)  # Frontal-Delaunay: well-shaped triangles
    gmsh.option.setNumber("Mesh.Optimize", 1)
    gmsh.model.mesh.generate(2)
    _, node_coords, _ = gmsh.model.mesh.getNodes()
    elem_types, elem_tags, elem_nodes = gmsh.model.mesh.getElements(2)
    tri = np.concatenate([n for t, n in zip(elem_types, elem_nodes) if t == 2]).reshape(-1, 3)
    xyz = node_coords.reshape(-1, 3)
    node_index = {int(tag): k for k, tag in enumerate(gmsh.model.mesh.getNodes()[0])}
    p = xyz[[node_index[int(t)] for t in tri.ravel()]].reshape(-1, 3, 3)[:, :, :2]
    angles = _triangle_angles(p)
    return _mesh_arrays(), coverage, {"nodes": int(len(np.unique(tri))), "triangles": int(len(tri)),
                      "min_angle_deg": float(angles.min()),
                      "fraction_below_20_deg": float(np.mean(angles.min(axis=1) < 20.0)),
                      "regions": int(len(covering)), "sliver_tolerance_mm": sliver}


def _distinct(chain: np.ndarray) -> np.ndarray:
    """The chain without points that repeat the one before (snapping can make them)."""
    step = np.linalg.norm(np.diff(chain, axis=0), axis=1)
    return chain[np.r_[True, step > 1e-9]]


def _box_with_marks(cell, on_x: np.ndarray, on_y: np.ndarray) -> int:
    """The cell as a polygon surface with vertices at the marks, on both sides of each pair."""
    import gmsh

    occ = gmsh.model.occ
    x0, x1, y0, y1 = cell.bounds
    ring = ([(x, y0) for x in np.r_[x0, on_y]] + [(x1, y) for y in np.r_[y0, on_x]]
            + [(x, y1) for x in np.r_[x1, on_y[::-1]]] + [(x0, y) for y in np.r_[y1, on_x[::-1]]])
    pts = [occ.addPoint(px, py, 0) for px, py in ring]
    lines = [occ.addLine(pts[k], pts[(k + 1) % len(pts)]) for k in range(len(pts))]
    return occ.addPlaneSurface([occ.addCurveLoop(lines)])


def _periodic_sides(cell, sliver: float) -> None:
    """Periodic sides: each right (top) boundary curve is a translated copy of a left (bottom) one;
    pair them by their centres of mass and make gmsh mesh them alike."""
    import gmsh

    occ = gmsh.model.occ
    x0, x1, y0, y1 = cell.bounds
    tol = max(sliver, 1e-6 * max(cell.lx, cell.ly))
    curves = [c for _, c in gmsh.model.getEntities(1)]
    centres = np.array([occ.getCenterOfMass(1, c) for c in curves]).reshape(-1, 3)
    for axis, (lo, hi) in ((0, (x0, x1)), (1, (y0, y1))):
        on_lo = [k for k, c in enumerate(curves) if _on_line(curves[k], axis, lo, tol)]
        on_hi = [k for k, c in enumerate(curves) if _on_line(curves[k], axis, hi, tol)]
        shift = np.zeros(3)
        shift[axis] = hi - lo
        masters, slaves = [], []
        for k in on_lo:
            d = np.linalg.norm(centres[on_hi] - (centres[k] + shift), axis=1) if on_hi else np.array([np.inf])
            j = int(np.argmin(d))
            if d[j] > tol:
                raise GeometryError(f"periodic boundary curves do not match across the cell: the curve "
                                    f"centred at {np.round(centres[k, :2], 4).tolist()} has no copy at "
                                    f"{'x' if axis == 0 else 'y'} = {hi:.4f} mm")
            masters.append(curves[k])
            slaves.append(curves[on_hi[j]])
        if len(set(slaves)) != len(on_hi):
            raise GeometryError(f"periodic boundary curves do not pair one to one along "
                                f"{'x' if axis == 0 else 'y'} ({len(on_lo)} vs {len(on_hi)} curves)")
        T = np.eye(4)
        T[axis, 3] = hi - lo
        gmsh.model.mesh.setPeriodic(1, slaves, masters, T.ravel().tolist())


def _mesh_arrays() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The triangles of every physical group of the gmsh model: node coordinates (N, 2) of the used
    nodes only, cells (M, 3) indexing them, and each cell's physical tag (M,)."""
    import gmsh

    tags, xyz, _ = gmsh.model.mesh.getNodes()
    cells, values = [], []
    for _, k in gmsh.model.getPhysicalGroups(2):
        for ent in gmsh.model.getEntitiesForPhysicalGroup(2, k):
            types, _, nodes = gmsh.model.mesh.getElements(2, ent)
            for etype, enodes in zip(types, nodes):
                if etype != 2:
                    raise GeometryError(f"gmsh produced elements of type {etype}, expected triangles")
                cells.append(enodes.reshape(-1, 3))
                values.append(np.full(len(cells[-1]), k, dtype=np.int32))
    cells = np.vstack(cells).astype(np.int64)
    used, compact = np.unique(cells, return_inverse=True)
    position = np.empty(int(tags.max()) + 1, dtype=np.int64)
    position[tags.astype(np.int64)] = np.arange(len(tags))
    x = xyz.reshape(-1, 3)[position[used], :2]
    return x, compact.reshape(-1, 3), np.concatenate(values)


def _to_dolfinx(comm, arrays, partitioner):
    """A distributed dolfinx mesh and its cell tags from rank 0's (x, cells, tags)."""
    import basix.ufl
    import ufl

    from dolfinx.io.utils import distribute_entity_data

    domain = ufl.Mesh(basix.ufl.element("Lagrange", "triangle", 1, shape=(2,)))
    if comm.rank == 0:
        x, cells, values = arrays
    else:
        x, cells, values = np.zeros((0, 2)), np.zeros((0, 3), np.int64), np.zeros(0, np.int32)
    msh = dolfinx.mesh.create_mesh(comm, cells, x, domain, partitioner)
    entities, local_values = distribute_entity_data(msh, 2, cells, values)
    msh.topology.create_connectivity(2, 0)
    adj = dolfinx.graph.adjacencylist(entities)
    tags = dolfinx.mesh.meshtags_from_entities(msh, 2, adj, local_values.astype(np.int32))
    tags.name = "covering_set"
    return msh, tags


def _ghost_strip(cell, x: np.ndarray, cells: np.ndarray, tags: np.ndarray):
    """The mesh arrays with the ghost strip added (DESIGN.md sections 6 and 11): the cells with an
    edge on the left (bottom) side are copied, shifted by the cell's width (height), beyond the
    right (top) side; a copy reuses the mesh's own nodes on the right (top) side, so the seam facets
    get a neighbour on each side and the solver can put the same facet terms on them as on interior
    facets. A copy of a region-k cell has tag k + GHOST."""
    x0, x1, y0, y1 = cell.bounds
    tol = 1e-9 * max(cell.lx, cell.ly)
    xs, cs, ts, n = [x], [cells], [tags], len(x)
    for axis, lo, hi, length in ((0, x0, x1, cell.lx), (1, y0, y1, cell.ly)):
        on_lo = np.abs(x[:, axis] - lo) < tol
        on_hi = np.flatnonzero(np.abs(x[:, axis] - hi) < tol)
        pick = on_lo[cells].sum(axis=1) >= 2
        chosen = cells[pick]
        side = np.unique(chosen[on_lo[chosen]])
        inner = np.unique(chosen[~on_lo[chosen]])
        other = 1 - axis  # a side node's partner: the node across the cell at the same coordinate
        if len(side) and len(on_hi):
            dist, k = cKDTree(x[on_hi][:, [other]]).query(x[side][:, [other]])
        else:
            dist, k = np.full(len(side), np.inf), np.zeros(len(side), int)
        if np.any(dist > 10 * tol):
            bad = x[side[np.argmax(dist)]]
            raise GeometryError(f"ghost strip: the boundary node at ({bad[0]:.6f}, {bad[1]:.6f}) mm has no periodic "
                                "partner on the opposite side")
        new = np.full(len(x), -1, np.int64)
        new[side] = on_hi[k]
        new[inner] = n + np.arange(len(inner))
        n += len(inner)
        shift = np.zeros(2)
        shift[axis] = length
        xs.append(x[inner] + shift)
        cs.append(new[chosen])
        ts.append(tags[pick] + GHOST)
    return np.vstack(xs), np.vstack(cs), np.concatenate(ts)


def _tile(x: np.ndarray, cells: np.ndarray, tags: np.ndarray, coverage: dict, coupon: Textile):
    """The unit cell's mesh arrays repeated over a coupon made by `coupon.tile`: coincident nodes
    on the repeats' common sides merged, each cell's unit-cell yarns replaced by the coupon's
    copies of them whose centrelines are nearest. Returns the coupon's arrays and coverage."""
    tiling = coupon.tiling
    unit = tiling.unit.cell
    shifts = [(i * unit.lx, j * unit.ly) for i in range(tiling.nx) for j in range(tiling.ny)]
    X = np.vstack([x + s for s in shifts])
    C = np.vstack([cells + r * len(x) for r in range(len(shifts))])
    T = np.tile(tags, len(shifts))
    # nodes of neighbouring repeats on their common side coincide (to round-off): one node each
    tol = 1e-9 * max(coupon.cell.lx, coupon.cell.ly)
    same = cKDTree(X).query_pairs(tol, output_type="ndarray")
    graph = scipy.sparse.coo_matrix((np.ones(len(same)), (same[:, 0], same[:, 1])), shape=(len(X), len(X)))
    _, label = connected_components(graph, directed=False)
    first = np.unique(label, return_index=True)[1]
    X, C = X[first], label[C]
    # unit yarn k over a cell -> the copy of k nearest to the cell's centre
    centre = X[C].mean(axis=1)
    copies = {}
    for i, k in enumerate(tiling.source):
        copies.setdefault(k, []).append(i)
    covering = [[] for _ in range(len(C))]
    for k, candidates in copies.items():
        over = np.flatnonzero(np.isin(T, [t for t, yarns in coverage.items() if k in yarns]))
        if len(over) == 0:
            continue
        d = np.column_stack([np.linalg.norm(coupon.nearest_centreline(c, centre[over])[0][:, :2] - centre[over], axis=1)
                             for c in candidates])
        order = np.argsort(d, axis=1)
        rows = np.arange(len(over))
        best = d[rows, order[:, 0]]
        second = d[rows, order[:, 1]] if len(candidates) > 1 else np.full(len(over), np.inf)
        if np.any(best > 0.5 * second):
            m = int(np.argmax(best / second))
            raise GeometryError(f"coupon mesh: the cell at ({centre[over[m], 0]:.3f}, {centre[over[m], 1]:.3f}) mm is "
                                f"nearly as close to two copies of {tiling.unit.yarns[k].name}; cannot tell "
                                "which covers it")
        for cell_index, c in zip(over, np.asarray(candidates)[order[:, 0]]):
            covering[cell_index].append(int(c))
    sets = [tuple(sorted(c)) for c in covering]
    tag_of = {s: t + 1 for t, s in enumerate(sorted(set(sets)))}
    return X, C, np.array([tag_of[s] for s in sets], np.int32), {t: s for s, t in tag_of.items()}


def _on_line(curve: int, axis: int, value: float, tol: float) -> bool:
    """Does gmsh curve `curve` lie on the line x[axis] = value (within tol)?"""
    import gmsh

    bb = gmsh.model.getBoundingBox(1, curve)
    return abs(bb[axis] - value) < tol and abs(bb[axis + 3] - value) < tol


def _triangle_angles(p: np.ndarray) -> np.ndarray:
    """Interior angles in degrees of triangles p (T, 3, 2)."""
    out = np.empty(p.shape[:2])
    for k in range(3):
        a, b, c = p[:, k], p[:, (k + 1) % 3], p[:, (k + 2) % 3]
        u, v = b - a, c - a
        cos = np.einsum("ij,ij->i", u, v) / (np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1))
        out[:, k] = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    return out


def release_freed_memory() -> None:
    """Return freed heap pages to the operating system (glibc), where available."""
    import ctypes
    import ctypes.util

    try:
        ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def projected_mesh(textile: Textile, options: MeshOptions = MeshOptions(),
                   comm: MPI.Comm = MPI.COMM_WORLD, bytes_per_dof: float = BYTES_PER_DOF) -> ProjectedMesh:
    """Mesh the cell by yarn coverage (gmsh on rank 0), distributed over `comm` (after the memory
    guard, check_memory, with the run's bytes per dof)."""
    check_memory(textile, options, comm.size, bytes_per_dof=bytes_per_dof)
    warnings = check_slopes(textile, options)
    return _mesh(textile, textile.cell, options, comm, warnings)


def plate_mesh(cell, seed: float, comm: MPI.Comm = MPI.COMM_WORLD) -> ProjectedMesh:
    """The periodic cell alone, meshed like a projected mesh (ghost strip included), as if one
    plate (index 0) covered it: for verification problems."""
    pm = _mesh(None, cell, MeshOptions(seed), comm, [])
    pm.coverage = {t: (0,) for t in pm.coverage}
    return pm


def _mesh(textile, cell, options, comm, warnings) -> ProjectedMesh:
    import gmsh

    start = time.perf_counter()
    name = textile.name if textile is not None else "plate"
    if options.seed > min(cell.lx, cell.ly):
        raise TextileError(f"mesh seed {options.seed:g} mm is larger than the cell "
                           f"({cell.lx:g} x {cell.ly:g} mm)")
    arrays, coverage, stats, error = None, None, {}, None
    initialised = gmsh.isInitialized()
    if not initialised:
        gmsh.initialize(interruptible=False)
    gmsh.option.setNumber("General.Terminal", 0)
    # OpenCASCADE's booleans on threads: the same meshes to the last bit (satin4, plain, twill22,
    # our orthogonal weave), 15-20 % less time. Not gmsh's threaded 2D meshing: its meshes differ
    # from run to run.
    gmsh.option.setNumber("Geometry.OCCParallel", 1)
    try:
        if comm.rank == 0:
            try:
                # a coupon: its unit cell is meshed, then repeated
                tiling = getattr(textile, "tiling", None)
                source = tiling.unit if tiling is not None else textile
                sliver = options.seed / 20 if options.sliver is None else options.sliver
                outlines = [(i, footprint_outlines(source, i, options.seed / 4, pad=3 * sliver))
                            for i in range(len(source.yarns))] if source is not None else []
                arrays, coverage, stats = _gmsh_model(source.cell if source is not None else cell, outlines,
                                                      options, f"projected-{name}")
                if tiling is not None:
                    *arrays, coverage = _tile(*arrays, coverage, textile)
                    stats.update(nodes=int(len(arrays[0])), triangles=int(len(arrays[1])), regions=len(coverage),
                                 tiled=[tiling.nx, tiling.ny])
                if cell.periodic:
                    arrays = _ghost_strip(cell, *arrays)
            except (TextileError, Exception) as e:  # report on every rank, never hang
                error = e
        error = comm.bcast(error, root=0)
        if error is not None:
            if isinstance(error, TextileError):
                raise error
            raise GeometryError(f"gmsh could not mesh the projected regions: {error}") from error
        coverage = comm.bcast(coverage, root=0)
        partitioner = dolfinx.mesh.create_cell_partitioner(dolfinx.mesh.GhostMode.shared_facet)
        msh, cell_tags = _to_dolfinx(comm, arrays, partitioner)
    finally:
        if comm.rank == 0:
            gmsh.model.remove()
        if not initialised:
            gmsh.finalize()
    msh.topology.create_connectivity(1, 2)
    release_freed_memory()  # gmsh/OCC's freed heap back to the system (it is large on coupons)
    stats = comm.bcast(stats, root=0)
    n_owned = msh.topology.index_map(2).size_local
    real = np.sum(cell_tags.values[cell_tags.indices < n_owned] < GHOST)
    stats.update(cells=comm.allreduce(int(real), op=MPI.SUM),
                 strip_cells=msh.topology.index_map(2).size_global - comm.allreduce(int(real), op=MPI.SUM),
                 seed_mm=options.seed, time_s=time.perf_counter() - start, warnings=warnings)
    log.info("mesh: seed %g mm: %d cells, %d nodes, %d regions, min angle %.1f deg, %.2f s", options.seed,
             stats["cells"], stats["nodes"], stats["regions"], stats["min_angle_deg"], stats["time_s"])
    return ProjectedMesh(msh, cell_tags, coverage, textile, options, stats, cell)
