"""Effective stiffness and conductivity of a periodic unit cell: the stage's one entry point.

    result = homogenise(mesh, cell_tags, direction, yarn_vf, fibre="t300", matrix="epoxy")
    result.C, result.constants, result.K, result.to_dict()   # stiffness.json

Collective: every rank calls it with its part of the mesh. Voigt order 11, 22, 33, 23, 13, 12
with engineering shear strains (constants.py); MPa, W/(m K), mm.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mpi4py import MPI

from textile_fenicsx.common import memory
from textile_fenicsx.common.errors import GeometryError
from textile_fenicsx.homogenisation.cellproblem import default_solver
from textile_fenicsx.homogenisation.conduction import ThermalCellProblem
from textile_fenicsx.homogenisation.constants import VOIGT_ORDER, bounds, engineering_constants
from textile_fenicsx.homogenisation.elasticity import ElasticCellProblem
from textile_fenicsx.homogenisation.fields import CellFields, yarn_fields
from textile_fenicsx.homogenisation.materials import material
from textile_fenicsx.homogenisation.periodic import Box, bounding_box
from textile_fenicsx.volume.refinement import error_summary

__all__ = ["Homogenised", "HomogeniseOptions", "estimated_bytes", "homogenise", "homogenise_fields"]

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class HomogeniseOptions:
    """degree: of the Lagrange elements (2: P2 on tetrahedra, Q2 on hexahedra); elasticity_solver,
    conduction_solver: PETSc options (plain dicts; by default cellproblem.default_solver(degree):
    p-multigrid over GAMG for degree 2 and up, CG_PMG, and CG + GAMG for degree 1, CG_GAMG);
    conduction: also the thermal problem (if the materials have conductivities); box: the periodic
    cell (default: the mesh's bounding box over all ranks); memory_limit: GB (default: the memory
    available now)."""
    degree: int = 2
    elasticity_solver: dict | None = None
    conduction_solver: dict | None = None
    conduction: bool = True
    box: Box | None = None
    memory_limit: float | None = None


@dataclass
class Homogenised:
    """C, S = C^-1 (6 x 6, MPa and 1/MPa), engineering constants, Voigt and Reuss bounds; K (3 x 3,
    W/(m K)) and its bounds or None; fibre and yarn volume fractions of the cell; dofs, CG
    iterations per load case and seconds per stage."""
    C: np.ndarray
    S: np.ndarray
    constants: dict
    voigt: np.ndarray
    reuss: np.ndarray
    asymmetry: float
    K: np.ndarray | None
    K_voigt: np.ndarray | None
    K_reuss: np.ndarray | None
    fibre_fraction: float
    yarn_fraction: float
    box: Box
    dofs: dict
    iterations: dict
    seconds: dict
    ranks: int
    materials: dict = field(default_factory=dict)
    error: dict | None = None  # the discretisation error's estimate (volume/refinement.py), where made

    def checks(self) -> dict:
        """The smallest eigenvalues of C, Voigt - C and C - Reuss over C's largest entry (positive:
        C is positive definite and within the bounds; rounding gives ~ -1e-12) and the asymmetry."""
        scale = float(np.abs(self.C).max())
        return {"asymmetry": self.asymmetry, "min_eig_C": float(np.linalg.eigvalsh(self.C).min()) / scale,
                "min_eig_voigt_minus_C": float(np.linalg.eigvalsh(self.voigt - self.C).min()) / scale,
                "min_eig_C_minus_reuss": float(np.linalg.eigvalsh(self.C - self.reuss).min()) / scale}

    def __repr__(self) -> str:
        c = self.constants
        return (f"Homogenised(Ex {c['Ex']:.0f}, Ey {c['Ey']:.0f}, Ez {c['Ez']:.0f}, Gxy {c['Gxy']:.0f} MPa, "
                f"nuxy {c['nuxy']:.3f}, Vf {self.fibre_fraction:.3f})")

    def summary(self) -> str:
        """One line: the engineering constants, the fibre fraction, the conductivities."""
        c = self.constants
        text = (f"Ex {c['Ex']:.0f} Ey {c['Ey']:.0f} Ez {c['Ez']:.0f} Gxy {c['Gxy']:.0f} Gxz {c['Gxz']:.0f} "
                f"Gyz {c['Gyz']:.0f} MPa, nuxy {c['nuxy']:.3f} nuxz {c['nuxz']:.3f} nuyz {c['nuyz']:.3f}, "
                f"Vf {self.fibre_fraction:.3f}")
        if self.K is not None:
            text += f"; kx {self.K[0, 0]:.3g} ky {self.K[1, 1]:.3g} kz {self.K[2, 2]:.3g} W/(m K)"
        return text + error_summary(self.error)

    def write(self, out, comm=None) -> Path:
        """stiffness.json in the folder `out` (created if missing; written whole, by rank 0)."""
        import json

        from textile_fenicsx.common.files import atomic_path, naming

        out = Path(out)
        comm = comm or MPI.COMM_WORLD
        if comm.rank == 0:
            with naming(out):
                out.mkdir(parents=True, exist_ok=True)
            with atomic_path(out / "stiffness.json") as tmp:
                tmp.write_text(json.dumps(self.to_dict(), indent=1))
        comm.barrier()
        return out / "stiffness.json"

    def to_dict(self) -> dict:
        """JSON-ready contents of stiffness.json."""
        def matrix(a):
            return None if a is None else np.asarray(a).tolist()

        return {
            "units": {"C": "MPa", "S": "1/MPa", "K": "W/(m K)", "lengths": "mm"},
            "voigt_order": list(VOIGT_ORDER),
            "shear": "engineering shear strains (gamma_ij = 2 eps_ij): sigma = C eps, eps = S sigma",
            "C": matrix(self.C), "S": matrix(self.S),
            "engineering_constants": {k: float(v) for k, v in self.constants.items()},
            "bounds": {"voigt": matrix(self.voigt), "reuss": matrix(self.reuss)},
            "checks": self.checks(),
            "error_estimate": self.error,
            "conductivity": None if self.K is None else {
                "K": matrix(self.K), "bounds": {"voigt": matrix(self.K_voigt), "reuss": matrix(self.K_reuss)}},
            "fibre_volume_fraction": self.fibre_fraction, "yarn_volume_fraction": self.yarn_fraction,
            "box": {"lo": list(self.box.lo), "hi": list(self.box.hi)},
            "materials": self.materials, "dofs": self.dofs, "iterations": self.iterations,
            "seconds": self.seconds, "ranks": self.ranks,
        }


def estimated_bytes(dofs: int, cell: str, ranks: int = 1, degree: int = 2) -> float:
    """Peak memory [bytes], summed over ranks, of homogenising with `dofs` elastic unknowns of the
    given degree: the serial figure per dof (memory.HOMOGENISE_BYTES_PER_DOF), grown by
    memory.HOMOGENISE_RANK_GROWTH for each rank beyond the first, and each rank's own."""
    per_dof = memory.HOMOGENISE_BYTES_PER_DOF.get((cell, degree), max(memory.HOMOGENISE_BYTES_PER_DOF.values()))
    growth = 1 + memory.HOMOGENISE_RANK_GROWTH * (ranks - 1)
    return dofs * per_dof * growth + ranks * memory.BYTES_PER_RANK


def homogenise(mesh, cell_tags, direction, yarn_vf, fibre, matrix,
               options: HomogeniseOptions | None = None) -> Homogenised:
    """Effective properties of a periodic cell whose yarns are fibre + matrix by Chamis' equations.

    mesh: DOLFINx mesh of tetrahedra or hexahedra filling its box; cell_tags: MeshTags (dim 3), 0 =
    matrix, 1 + i = yarn i; direction: DG0 vector Function, the unit fibre direction per cell
    (ignored in the matrix); yarn_vf: DG0 Function, the intra-yarn fibre volume fraction (ignored in
    the matrix); fibre, matrix: Materials, preset names or TOML files (materials.py).
    """
    t0 = time.perf_counter()
    fibre, matrix = material(fibre), material(matrix)
    fields = yarn_fields(mesh, cell_tags, direction, yarn_vf, fibre, matrix)
    t_fields = time.perf_counter() - t0
    result = homogenise_fields(fields, options)
    result.materials = {"fibre": {"name": fibre.name, "source": fibre.source},
                        "matrix": {"name": matrix.name, "source": matrix.source},
                        "yarn": "Chamis, SAMPE Quarterly 15(3) 1984, at each cell's fibre volume fraction"}
    result.seconds["properties"] = t_fields
    result.seconds["total"] += t_fields
    return result


def _solve(problem_type, field_, box, solver, degree, volume, tensors, cell_volumes, comm, seconds, key):
    problem = problem_type(field_, box, solver, degree)
    try:
        out = problem.fluctuation_energies()
        seconds[f"{key}_assembly"] = problem.assembly_seconds
        seconds[f"{key}_preconditioner"] = problem.pc_seconds
        seconds[f"{key}_solves"] = out["seconds"]
        dofs = problem.dofs
    finally:
        problem.destroy()
    mean = np.einsum("c,cij->ij", cell_volumes, tensors)
    comm.Allreduce(mean.copy(), mean)
    A = (mean + out["energy"]) / volume
    return A, dofs, out["iterations"]


def homogenise_fields(fields: CellFields, options: HomogeniseOptions | None = None) -> Homogenised:
    """Effective properties of the per-cell fields (fields.yarn_fields or fields.phase_fields)."""
    options = options or HomogeniseOptions()
    mesh = fields.D.function_space.mesh
    comm = mesh.comm
    start = time.perf_counter()
    box = options.box or bounding_box(mesh)
    volume = comm.allreduce(float(fields.volumes.sum()), op=MPI.SUM)
    if abs(volume - box.volume) > 1e-6 * box.volume:
        raise GeometryError(f"the mesh's volume {volume:.6g} mm^3 is not its periodic box's {box.volume:.6g} mm^3 "
                            "(a unit cell's mesh must fill its box)")
    cell = mesh.topology.cell_name()
    nodes = _nodes(mesh, options.degree)
    memory.check(estimated_bytes(3 * nodes, cell, comm.size, options.degree),
                 what=f"homogenising with {3 * nodes} elastic unknowns ({cell}, degree {options.degree}) would",
                 hint="use a coarser volume mesh", limit_gb=options.memory_limit)
    seconds: dict = {}
    dofs: dict = {}
    iterations: dict = {}
    solvers = (options.elasticity_solver or default_solver(options.degree),
               options.conduction_solver or default_solver(options.degree))
    C, dofs["elasticity"], iterations["elasticity"] = _solve(
        ElasticCellProblem, fields.D, box, solvers[0], options.degree, volume, fields.stiffness,
        fields.volumes, comm, seconds, "elasticity")
    asymmetry = float(np.abs(C - C.T).max() / np.abs(C).max())
    C = 0.5 * (C + C.T)
    voigt, reuss = bounds(fields.stiffness, fields.volumes, comm)
    K = K_voigt = K_reuss = None
    if options.conduction and fields.K is not None and fields.conductivity is not None:
        K, dofs["conduction"], iterations["conduction"] = _solve(
            ThermalCellProblem, fields.K, box, solvers[1], options.degree, volume,
            fields.conductivity, fields.volumes, comm, seconds, "conduction")
        K = 0.5 * (K + K.T)
        K_voigt, K_reuss = bounds(fields.conductivity, fields.volumes, comm)
    fibre = comm.allreduce(float(fields.volumes @ fields.fibre_fraction), op=MPI.SUM) / volume
    yarn = comm.allreduce(float(fields.volumes[fields.yarn].sum()), op=MPI.SUM) / volume
    seconds["total"] = time.perf_counter() - start
    result = Homogenised(C=C, S=np.linalg.inv(C), constants=engineering_constants(C), voigt=voigt, reuss=reuss,
                         asymmetry=asymmetry, K=K, K_voigt=K_voigt, K_reuss=K_reuss, fibre_fraction=fibre,
                         yarn_fraction=yarn, box=box, dofs=dofs, iterations=iterations, seconds=seconds,
                         ranks=comm.size)
    c = result.constants
    log.info(f"homogenised ({dofs['elasticity']} dofs, {seconds['total']:.1f} s): Ex {c['Ex']:.0f} Ey {c['Ey']:.0f} "
             f"Ez {c['Ez']:.0f} Gxy {c['Gxy']:.0f} Gxz {c['Gxz']:.0f} Gyz {c['Gyz']:.0f} MPa, nuxy {c['nuxy']:.3f} "
             f"nuxz {c['nuxz']:.3f} nuyz {c['nuyz']:.3f}"
             + ("" if K is None else f"; kx {K[0, 0]:.3g} ky {K[1, 1]:.3g} kz {K[2, 2]:.3g} W/(m K)"))
    return result


def _nodes(mesh, degree: int) -> int:
    """Lagrange nodes of this degree on the mesh (global), from its entity counts."""
    top = mesh.topology
    dims: tuple[int, ...]
    if degree == 1:
        dims = (0,)
    elif degree == 2:
        dims = (0, 1) if top.cell_name() == "tetrahedron" else (0, 1, 2, 3)
    else:
        return top.index_map(0).size_global * degree**3
    for d in dims:
        top.create_entities(d)
    return sum(top.index_map(d).size_global for d in dims)
