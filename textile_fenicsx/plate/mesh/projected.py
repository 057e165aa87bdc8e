"""The projected-region mesh of the unit cell (DESIGN.md section 4): what it is and how it is made.

`projected_mesh(textile, options, comm)` checks the seed against the memory (memory.py, from the
estimate `estimated_dofs`) and the yarns' slopes, then:
1. footprints.py: each yarn's outline seen along z;
2. regions.py (with periodic_sides.py): the gmsh model of the regions each covered by a fixed set
   of yarns, meshed on rank 0; a coupon made by `coupon.tile` has its unit cell meshed and the
   triangles repeated (tiling.py);
3. conversion.py: the ghost strip along the periodic seams, then the distributed DOLFINx mesh.
The result is a `ProjectedMesh`: the mesh, its cell tags and which yarns cover each tag.
"""

import logging
import time
from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI

import dolfinx
from textile_fenicsx.common import limits, memory
from textile_fenicsx.common.errors import GeometryError, TextileError
from textile_fenicsx.model.textile import Cell, Textile
from textile_fenicsx.plate.mesh.conversion import GHOST, ghost_strip, to_dolfinx
from textile_fenicsx.plate.mesh.footprints import footprint_area, footprint_outlines, snap_to_neighbours
from textile_fenicsx.plate.mesh.periodic_sides import outlines_on_sides, snap_to_sides
from textile_fenicsx.plate.mesh.regions import fresh_start, gmsh_session, region_mesh
from textile_fenicsx.plate.mesh.tiling import tile_arrays

__all__ = ["GHOST", "MeshOptions", "ProjectedMesh", "check_memory", "check_slopes", "estimated_dofs", "plate_mesh",
           "projected_mesh"]

log = logging.getLogger(__name__)

# Where gmsh cannot mesh the regions, they are made again with the side chains of the footprints
# that stay within SNAP[k] x the sliver tolerance of an earlier yarn's (wherever they are over the
# cell) replaced by it (footprints.snap_to_neighbours), k = 0, 1, ...: two edges that leave each
# other at a tiny angle are not merged by OpenCASCADE's boolean, and the wedge between them has a
# corner of no angle, which gmsh cannot mesh ("Unable to recover the edge"). TexGen's refined
# orthogonal weaves have them in every weft column (outer wefts 2.58 to 2.64 mm wide, blended with
# a ramp, beside a middle weft 2.58 mm wide: 0.03 mm apart at most); at the default seed 0.5 mm the
# first try does (0.05 mm), at 0.25 mm the second.
SNAP = (2.0, 4.0)
# and where that fails too, once more with the footprints' points within SIDE_SNAP x the sliver
# tolerance of a cell side put onto it (periodic_sides.snap_to_sides puts those within 1 x):
# gmsh's boolean merges a point about its tolerance from a side onto it or not, at round-off's
# whim, and the two sides' curves then do not pair. TexGen's orthogonal weave at seed 0.25 mm has
# its binders' edges 0.0125 mm inside its y sides, and the tolerance is seed / 20 = 0.0125 mm
SIDE_SNAP = 2.0
# Mesh nodes this close to a cell side, over the cell's size, are put exactly on it (_mesh_on_root).
SIDE_NODES = 1e-9



@dataclass(frozen=True)
class MeshOptions:
    """Projected-mesh settings.

    seed: target element size [mm]. sliver: edges of different yarns closer than this [mm] are merged
    (default seed / 20; where gmsh cannot mesh the regions so, they are made again with such edges
    put together beforehand: `_regions`). max_slope: steepest centreline slope |dz| / |dxy| the
    method accepts; above it the through-thickness part of a yarn is narrower in plan than a tenth
    of its rise and cannot be a plate (default 10, i.e. 84 degrees). allow_steep: warn instead of
    stopping.
    memory_limit: largest memory [GB] a run may need (estimated from the seed before meshing; default
    the memory the system has available); a finer seed is refused, saying how much it would need.
    """

    seed: float = 0.5
    sliver: float | None = None
    max_slope: float = 10.0
    allow_steep: bool = False
    memory_limit: float | None = None

    def __post_init__(self) -> None:
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


def check_memory(textile: Textile, options: MeshOptions, ranks: int, repeats: tuple[int, int] = (1, 1),
                 bytes_per_dof: float = memory.BYTES_PER_DOF) -> None:
    """Refuse, before meshing (and before tiling a coupon of `repeats` unit cells), a seed whose
    run would need more memory than the limit (memory.check; bytes_per_dof: memory.BYTES_PER_DOF,
    or BYTES_PER_DOF_OUT_OF_CORE for a solve with MUMPS' factors on disk)."""
    dofs = estimated_dofs(textile, options.seed, repeats)
    tiling = getattr(textile, "tiling", None)
    nx, ny = (tiling.nx, tiling.ny) if tiling is not None else (1, 1)
    nx, ny = nx * repeats[0], ny * repeats[1]
    coupon = f"a {nx} x {ny} coupon at " if (nx, ny) != (1, 1) else ""
    memory.check(dofs * bytes_per_dof + ranks * memory.BYTES_PER_RANK,
                 what=f"{coupon}mesh seed {options.seed:g} mm would give about {dofs:.3g} unknowns and",
                 hint=f"use a larger seed{' or fewer repeats' if coupon else ''}", limit_gb=options.memory_limit)


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
    textile: Textile | None  # None for plate_mesh's verification plates
    options: MeshOptions
    stats: dict = field(default_factory=dict)
    cell: Cell | None = None

    def __repr__(self) -> str:
        name = self.textile.name if self.textile is not None else "a plate"
        return (f"<ProjectedMesh of {name!r}: {self.stats.get('cells')} cells, {self.stats.get('nodes')} nodes, "
                f"{len(self.coverage)} covering sets, seed {self.options.seed:g} mm>")

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


def projected_mesh(textile: Textile, options: MeshOptions = MeshOptions(),
                   comm: MPI.Comm = MPI.COMM_WORLD, bytes_per_dof: float = memory.BYTES_PER_DOF) -> ProjectedMesh:
    """Mesh the cell by yarn coverage (gmsh on rank 0), distributed over `comm` (after the memory
    guard, check_memory, with the run's bytes per dof)."""
    check_memory(textile, options, comm.size, bytes_per_dof=bytes_per_dof)
    warnings = check_slopes(textile, options)
    return _mesh(textile, textile.cell, options, comm, warnings)


def plate_mesh(cell: Cell, seed: float, comm: MPI.Comm = MPI.COMM_WORLD) -> ProjectedMesh:
    """The periodic cell alone, meshed like a projected mesh (ghost strip included), as if one
    plate (index 0) covered it: for verification problems."""
    pm = _mesh(None, cell, MeshOptions(seed), comm, [])
    pm.coverage = {t: (0,) for t in pm.coverage}
    return pm


def _mesh(textile: Textile | None, cell: Cell, options: MeshOptions, comm: MPI.Comm,
          warnings: list[str]) -> ProjectedMesh:
    start = time.perf_counter()
    name = textile.name if textile is not None else "plate"
    if options.seed > min(cell.lx, cell.ly):
        raise TextileError(f"mesh seed {options.seed:g} mm is larger than the cell "
                           f"({cell.lx:g} x {cell.ly:g} mm)")
    with gmsh_session(owner=comm.rank == 0):
        made = _mesh_on_root(textile, cell, options, name) if comm.rank == 0 else None
        error = comm.bcast(made if isinstance(made, Exception) else None, root=0)  # on every rank, never hang
        if error is not None:
            if isinstance(error, TextileError):
                raise error
            raise GeometryError(f"gmsh could not mesh the projected regions: {error}") from error
        arrays, coverage, stats = made if isinstance(made, tuple) else (None, None, {})
        coverage = comm.bcast(coverage, root=0)
        partitioner = dolfinx.mesh.create_cell_partitioner(dolfinx.mesh.GhostMode.shared_facet)
        msh, cell_tags = to_dolfinx(comm, arrays, partitioner)
    msh.topology.create_connectivity(1, 2)
    memory.release_freed_memory()  # gmsh/OCC's freed heap back to the system (it is large on coupons)
    stats = comm.bcast(stats, root=0)
    n_owned = msh.topology.index_map(2).size_local
    real = np.sum(cell_tags.values[cell_tags.indices < n_owned] < GHOST)
    stats.update(cells=comm.allreduce(int(real), op=MPI.SUM),
                 strip_cells=msh.topology.index_map(2).size_global - comm.allreduce(int(real), op=MPI.SUM),
                 seed_mm=options.seed, time_s=time.perf_counter() - start, warnings=warnings)
    log.info("mesh: seed %g mm: %d cells, %d nodes, %d regions, min angle %.1f deg, %.2f s", options.seed,
             stats["cells"], stats["nodes"], stats["regions"], stats["min_angle_deg"], stats["time_s"])
    return ProjectedMesh(msh, cell_tags, coverage, textile, options, stats, cell)


def _mesh_on_root(textile: Textile | None, cell: Cell, options: MeshOptions,
                  name: str) -> tuple[tuple | list, dict, dict] | Exception:
    """Rank 0's part: the gmsh model (of a coupon's unit cell, then tiled) and the ghost strip, as
    (arrays, coverage, stats), or the exception that stopped it (to be reported on every rank)."""
    try:
        # a coupon: its unit cell is meshed, then repeated
        tiling = getattr(textile, "tiling", None)
        source = tiling.unit if tiling is not None else textile
        arrays, coverage, stats = _regions(source, cell, options, name)
        if tiling is not None:
            assert textile is not None  # the coupon
            x, cells, tags, coverage = tile_arrays(*arrays, coverage, textile)
            arrays = (x, cells, tags)
            stats.update(nodes=int(len(x)), triangles=int(len(cells)), regions=len(coverage),
                         tiled=[tiling.nx, tiling.ny])
        # side nodes exactly on the sides: gmsh left some up to 2e-14 mm off, and a yarn whose
        # centreline runs along a side (a loose ply moved by half a spacing) was then outside its
        # own plate for DOLFINx's point search
        x, cells, tags = arrays
        arrays = (snap_to_sides(x, cell, SIDE_NODES * max(cell.lx, cell.ly)), cells, tags)
        if cell.periodic:
            arrays = ghost_strip(cell, *arrays)
        return arrays, coverage, stats
    except Exception as e:  # reported on every rank by _mesh
        return e


def _regions(source: Textile | None, cell: Cell, options: MeshOptions,
             name: str) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], dict, dict]:
    """region_mesh of the footprints; where gmsh cannot mesh them, again with the side chains that
    stay within SNAP x the sliver tolerance of an earlier yarn's put onto it beforehand
    (footprints.snap_to_neighbours), each factor in turn, and then with the points within
    SIDE_SNAP x of a cell side put onto it. A model that meshes as it is is meshed as it always
    was; the first failure is raised if every try fails."""
    sliver = options.seed / 20 if options.sliver is None else options.sliver
    outlines = [(i, footprint_outlines(source, i, options.seed / 4, pad=3 * sliver))
                for i in range(len(source.yarns))] if source is not None else []
    where = source.cell if source is not None else cell
    try:
        return region_mesh(where, outlines, options.seed, sliver, f"projected-{name}")
    except Exception as e:
        if not outlines:
            raise
        first = e
    for factor in SNAP:
        log.warning("mesh: gmsh could not mesh the projected regions (%s); meshing them again with yarn edges "
                    "that stay within %g mm of another's made one", first, factor * sliver)
        fresh_start()
        try:
            return region_mesh(where, snap_to_neighbours(outlines, factor * sliver, where), options.seed, sliver,
                               f"projected-{name}")
        except Exception:
            pass
    log.warning("mesh: gmsh could not mesh the projected regions (%s); meshing them again with yarn edges that "
                "stay within %g mm of a cell side put onto it", first, SIDE_SNAP * sliver)
    fresh_start()
    try:
        return region_mesh(where, outlines_on_sides(outlines, where, SIDE_SNAP * sliver), options.seed, sliver,
                           f"projected-{name}")
    except Exception:
        pass
    raise first
