"""The memory guard: what a run may take, checked before it is built, and freed memory given back.

Every stage that builds something large (the projected mesh and its solve, a coupon, the volume
mesh to come) estimates the bytes it will need and calls `check` before it starts, so that a seed
too fine for the machine is refused in a second with a message that says how much it would need,
instead of a run that swaps or is killed an hour later:

    from textile_fenicsx.common import memory
    memory.check(dofs * memory.BYTES_PER_DOF + ranks * memory.BYTES_PER_RANK,
                 what="mesh seed 0.1 mm would give about 2e6 unknowns and",
                 hint="use a larger seed", limit_gb=None)
"""

import ctypes
import ctypes.util

from textile_fenicsx.common.errors import TextileError

__all__ = ["BYTES_PER_DOF", "BYTES_PER_DOF_OUT_OF_CORE", "BYTES_PER_RANK", "HOMOGENISE_BYTES_PER_DOF",
           "HOMOGENISE_RANK_GROWTH",
           "available_memory", "check", "release_freed_memory"]

# Memory of a plate solve per unknown [bytes], measured by `make bench` (satin coupons, summed peaks:
# 3.3e5 dofs on 1 and 2 ranks 5.8 and 7.5 kB per dof, 1.3e6 dofs on 2 ranks 6.9 kB per dof, with
# MUMPS' factors and the outputs), and per process.
BYTES_PER_DOF = 8e3
# the same with MUMPS' factors on disk (SolverOptions.out_of_core)
BYTES_PER_DOF_OUT_OF_CORE = 6e3
BYTES_PER_RANK = 0.3e9
# Peak memory of homogenising per elastic unknown and rank [bytes] (matrix, GAMG hierarchy, vectors,
# mesh, fields), from bench/homogenise_bench.py (2026-11-25): serially, P2 tetrahedra 2.5 kB/dof
# (0.40, 0.91, 1.59 GB at 100k, 300k, 584k dofs) and Q2 hexahedra 4.4 kB/dof (0.59, 1.47 GB at 100k,
# 300k: 27-node cells, about twice the entries per row); on 2 ranks the sum over ranks is 5.2 and
# 6.6 kB/dof (GAMG's parallel setup), so estimates scale the per-dof part with the ranks. First
# order has fewer entries per row: Q1 hexahedra on 2 ranks peaked at 2.49 GB per rank with 1.17e6
# dofs (2026-11-26, the voxel satin of docs/volume.md's refinement study), 1.9 kB/dof and rank; P1 tets
# are not measured, and take P2's figure. Since 2026-11-27 the elastic operator is also held in
# block CSR (cellproblem.py): bench/volume_bench.py then measured serially 3.5 kB/dof on P2
# tetrahedra (4.62 and 6.13 GB at 1.33 and 1.76 M dofs) and 6.3 kB/dof on Q2 hexahedra (2.66 GB at
# 421k). Q1 hexahedra: their 2026-11-26 peak on 2 ranks, at most 2 x 2.49 GB for 1.17 M dofs (4.3
# kB/dof summed), over the growth below for the second rank.
HOMOGENISE_BYTES_PER_DOF = {("tetrahedron", 2): 3.6e3, ("hexahedron", 2): 6.5e3,
                            ("tetrahedron", 1): 3.6e3, ("hexahedron", 1): 3.5e3}
# The unknowns are shared by the ranks, so the sum over ranks grows little beyond the serial figure:
# the voxel satin's default grid (1.25 M Q2 unknowns, 2026-12-07) peaked at 6.8 GB on one rank and
# 3.5 GB a rank on two (7.0 GB, +3 %). The estimate allows 25 % more a rank beyond the first (it
# counted the serial figure on every rank until then, and refused that grid on two ranks).
HOMOGENISE_RANK_GROWTH = 0.25


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


# The flow cell problem's direct solve (flow/problem.py: MUMPS' LU of the Taylor-Hood saddle point):
# 2.98 GB peak for 123 901 unknowns on one rank, 2.16 GB a rank on two (the corrected satin's voxels at
# 0.3 mm, Q2-Q1, 2026-12-07): 24 kB an unknown there, the fill of a 3D factor growing as n^(4/3)
FLOW_BYTES_PER_DOF = 24e3
FLOW_REFERENCE_DOFS = 1.24e5


# Its iterative solve (the matrix and its reduction R^T A R, the fieldsplit's blocks, the velocity's
# P1 coarse level and BoomerAMG's hierarchies on it and on the pressure, the Krylov vectors) grows as
# the matrix's entries. With the velocity's two-level p-multigrid (flow/problem.py ITERATIVE,
# 2026-12-08) the peak was 6.46 GB on one rank and 3.08 GB a rank on two on the corrected satin's
# tet mesh at 1.0 mm (936 842 Taylor-Hood unknowns, 90.7 M entries): 71 and 68 bytes an entry
# (the most loaded rank's twice), set mostly by the assembly and R^T A R; on the satin's 0.3 mm
# voxels (123 901 unknowns, 23.3 M entries) 1.51 GB serially, 65 bytes an entry. BoomerAMG on the
# P2 velocity itself (ITERATIVE_AMG) took 8.4 GB and 4.3-5.5 GB a rank there: 93-121 bytes an
# entry. The entries a row, by cell (Taylor-Hood of degree 2, measured on those two meshes): a
# voxel cell needs twice a tet cell's memory for its unknowns
FLOW_ITERATIVE_BYTES_PER_ENTRY = 80
FLOW_ENTRIES_PER_ROW = {"tetrahedron": 97, "hexahedron": 188}


def flow_bytes(dofs: int, direct: bool = True, cell: str = "hexahedron") -> float:
    """The flow cell problem's estimated peak [bytes] for `dofs` unknowns on cells of the kind
    `cell`, by a direct solve (FLOW_BYTES_PER_DOF) or an iterative one (FLOW_ITERATIVE_BYTES_PER_ENTRY)."""
    if not direct:
        return FLOW_ITERATIVE_BYTES_PER_ENTRY * FLOW_ENTRIES_PER_ROW.get(cell, 188) * dofs
    return FLOW_BYTES_PER_DOF * dofs * max(1.0, dofs / FLOW_REFERENCE_DOFS) ** (1 / 3)


def check(bytes_needed: float, what: str, hint: str, limit_gb: float | None = None) -> None:
    """Raise TextileError if a stage would need more than `limit_gb` [GB] (None: the memory
    available now). The message reads "{what} need about N GB, more than {the limit} (L GB);
    {hint} (or --memory-limit if you know better)": `what` names the thing to be built and its
    size, ending where "need" follows; `hint` says what to change."""
    limit = available_memory() if limit_gb is None else limit_gb * 1e9
    if bytes_needed > limit:
        which = "the memory limit you gave" if limit_gb is not None else "the memory available now"
        raise TextileError(f"{what} need about {bytes_needed / 1e9:.1f} GB, more than {which} ({limit / 1e9:.1f} GB); "
                           f"{hint} (or --memory-limit if you know better)")


def release_freed_memory() -> None:
    """Return freed heap pages to the operating system (glibc), where available."""
    try:
        ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
