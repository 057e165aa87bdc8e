"""The periodic flow cell problem: Taylor-Hood velocity-pressure on the volume mesh, three load cases.

The unknowns live in one mixed space W = (P2)^3 x P1 (Q2 x Q1 on voxels): dolfinx_mpc 0.9's
constraints on a sub-space of a mixed space miss dofs (its issue 235), and its block assembly with
two constrained fields had a wrong sparsity pattern (issues 215/216), so the periodicity is applied
here by PETSc alone: the whole system is assembled without it, and reduced to R^T A R
(reduction.py), its slave and held rows the identity's. The three load cases share one operator:
it is factorised once (DIRECT: MUMPS LU; a saddle point) or preconditioned once (ITERATIVE: FGMRES
with a block preconditioner), as choose_solver picks by the size of the problem.
"""

from __future__ import annotations

import itertools
import logging
import time

import basix.ufl
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
from textile_fenicsx.common import memory
from textile_fenicsx.common.errors import SolverError
from textile_fenicsx.common.petsc import petsc_options
from textile_fenicsx.flow.forms import stokes_brinkman_forms
from textile_fenicsx.flow.pmultigrid import velocity_coarse_level
from textile_fenicsx.flow.reduction import periodic_reduction, reduced
from textile_fenicsx.homogenisation.cellproblem import cell_measure
from textile_fenicsx.homogenisation.periodic import Box
from textile_fenicsx.plate.solver.linear import DIRECT_LU, DirectSolver

__all__ = ["DIRECT", "ITERATIVE", "ITERATIVE_AMG", "FlowCellProblem", "choose_solver"]

log = logging.getLogger(__name__)

# A saddle point of a few hundred thousand unknowns: MUMPS' LU with its own pivoting (the plate
# solver's DIRECT_LU and DirectSolver: options under a prefix, removed once read)
DIRECT = DIRECT_LU

# FGMRES on the whole saddle point, preconditioned by its block factorisation (PCFIELDSPLIT,
# Schur, upper). The Schur complement S = -B A^-1 B^T by B diag(A)^-1 B^T ("selfp", a discrete
# Laplacian weighted by the velocity block's diagonal: mu (c / h^2 + k) there, so Darcy's K / mu
# in the yarns and h^2 / mu in the pores) and one V-cycle of BoomerAMG, with BoomerAMG's defaults
# (Falgout, classical, 0.25): with the velocity's settings (below) it stalled where solid yarns
# hold thousands of pressure dofs (the satin's 0.3 mm voxels: the residual stuck at 0.04 of the
# load's), and took 20 iterations with these.
# Measured on the corrected satin's voxel cells (2026-12-07; docs/permeability.md, make
# bench-flow): the drag-weighted pressure mass matrix (Cahouet-Chabard's Stokes term, w = 1 / (mu
# (1 + h^2 k / c))) took 150-200 iterations at 0.6 mm where selfp took 16-26: the pores' thin
# channels, where S is far below the mass matrix. The velocity block by LU instead of AMG took the
# same iterations at 0.6 mm (not at 0.3 mm: below). A residual of 1e-6 of the load's moves K by
# under 1e-6 of its largest entry (1e-8 took 48 iterations where 1e-6 took 19).
_SCHUR = {
    "ksp_type": "fgmres",
    "ksp_rtol": 1e-6,
    "ksp_atol": 0.0,
    "ksp_max_it": 1000,
    "ksp_gmres_restart": 200,
    "pc_type": "fieldsplit",
    "pc_fieldsplit_type": "schur",
    "pc_fieldsplit_schur_fact_type": "upper",
    "pc_fieldsplit_schur_precondition": "selfp",
    "fieldsplit_u_ksp_type": "preonly",
    "fieldsplit_p_ksp_type": "preonly",
    "fieldsplit_p_pc_type": "hypre",
    "fieldsplit_p_pc_hypre_type": "boomeramg",
}
# The velocity's BoomerAMG: HMIS coarsening with extended+i interpolation, strength 0.5 and one level
# of aggressive coarsening (the three-dimensional settings of hypre's manual)
_VELOCITY_AMG = {"pc_type": "hypre", "pc_hypre_type": "boomeramg", "pc_hypre_boomeramg_coarsen_type": "HMIS",
                 "pc_hypre_boomeramg_interp_type": "ext+i", "pc_hypre_boomeramg_strong_threshold": 0.5,
                 "pc_hypre_boomeramg_agg_nl": 1}

# The velocity block by two-level p-multigrid (pmultigrid.py): the P2 (Q2) velocity smoothed by two
# sweeps of SOR (PETSc's: symmetric Gauss-Seidel on each rank's rows) before and after the coarse
# correction; the coarse level the P1 (Q1) velocity on the same mesh, its Galerkin operator
# assembled on P1, by one V-cycle of the velocity's BoomerAMG. The Schur block as before (selfp).
# Measured on the corrected satin's tet cell at 1.0 mm (936 842 unknowns, Gebart's yarns, 2 ranks
# of a 2-core machine shared with other jobs, 2026-12-08; docs/permeability.md, Measured):
# BoomerAMG on P2 itself (ITERATIVE_AMG) 40/40/40 iterations, 4.3-4.4 GB a rank, 273 s; one SOR
# sweep, run after it at the same load (4-5), 39/38/38, 2.9 GB a rank, 218 s: hypre's copy of the
# P2 block and its hierarchy were 1.2-1.4 GB a rank, and a SOR sweep costs about what hypre's
# V-cycle on P2 did. Two sweeps: 28/27/27 iterations, each about 1.5 x dearer; on the satin's 0.3
# mm voxels (124 k unknowns, serial, alternating runs) 35 iterations instead of 55 and no slower.
# Chebyshev (degree 2) with Jacobi instead of SOR: 57 iterations on the tets. With the velocity
# block solved exactly the 0.3 mm voxels took 18-19: the block's V-cycle sets most of them.
ITERATIVE = {
    **_SCHUR,
    "fieldsplit_u_pc_type": "mg",
    "fieldsplit_u_pc_mg_levels": 2,
    "fieldsplit_u_pc_mg_galerkin": "none",
    "fieldsplit_u_mg_levels_ksp_type": "richardson",
    "fieldsplit_u_mg_levels_ksp_max_it": 2,
    "fieldsplit_u_mg_levels_pc_type": "sor",
    "fieldsplit_u_mg_coarse_ksp_type": "preonly",
    **{"fieldsplit_u_mg_coarse_" + key: value for key, value in _VELOCITY_AMG.items()},
}

# The first (to 2026-12-07): the velocity block by one V-cycle of the velocity's BoomerAMG on P2 itself
ITERATIVE_AMG = {**_SCHUR, **{"fieldsplit_u_" + key: value for key, value in _VELOCITY_AMG.items()}}

# The direct solve where it is small enough: below this many unknowns it was faster than the
# iterative one on the satin's voxel cells (24 k: 3.3 s against 10.6; 124 k: 25 s against 120)
DIRECT_MAX_DOFS = 150_000

_serial = itertools.count()


def choose_solver(dofs: int, memory_limit: float | None = None) -> dict:
    """The options of the flow problem's solve: DIRECT up to DIRECT_MAX_DOFS unknowns where its
    factor fits in memory (memory_limit [GB], None: what is available), else ITERATIVE."""
    limit = memory.available_memory() if memory_limit is None else memory_limit * 1e9
    small = dofs <= DIRECT_MAX_DOFS and memory.flow_bytes(dofs) <= limit
    return dict(DIRECT if small else ITERATIVE)


class FlowCellProblem:
    """The Stokes-Brinkman cell (forms.py) of a DG0 inverse permeability K_inv [mm^-2] (0 in the
    pores), on the periodic box `box`. solid: a boolean per local cell (owned and ghost), True where
    the yarns are impermeable (no-slip on their surfaces), or None. mu: the viscosity [Pa s].
    memory_limit [GB]: refuse a problem whose direct solve would need more (None: what is available).
    options: PETSc's (DIRECT, ITERATIVE, ITERATIVE_AMG or one's own; None: choose_solver's);
    description: the solver's, in words. `destroy()` frees the PETSc objects."""

    def __init__(self, K_inv: dolfinx.fem.Function, box: Box, degree: int = 2, mu: float = 1.0,
                 solid: np.ndarray | None = None, options: dict | None = None, memory_limit: float | None = None):
        mesh = K_inv.function_space.mesh
        self.comm, self.box, self.mu = mesh.comm, box, mu
        self._objects: list = []
        t0 = time.perf_counter()
        cell = mesh.basix_cell()
        element = basix.ufl.mixed_element([basix.ufl.element("Lagrange", cell, degree, shape=(3,)),
                                           basix.ufl.element("Lagrange", cell, degree - 1)])
        self.W = dolfinx.fem.functionspace(mesh, element)
        options = dict(options) if options is not None else self.comm.bcast(choose_solver(self.dofs, memory_limit))
        self.iterative = options.get("pc_type") == "fieldsplit"
        velocity = ("p-multigrid (P2 by SOR, P1 by BoomerAMG)" if options.get("fieldsplit_u_pc_type") == "mg"
                    else "BoomerAMG")
        self.description = (f"FGMRES, block preconditioner (Schur, upper): {velocity} on the velocity, selfp + "
                            f"BoomerAMG on the pressure; rtol {options.get('ksp_rtol', 0):g}" if self.iterative else
                            "MUMPS LU (direct), one factorisation for the three load cases")
        how = "iterative" if self.iterative else "direct"
        memory.check(memory.flow_bytes(self.dofs, not self.iterative, mesh.topology.cell_name()),
                     what=f"the flow problem's {self.dofs} unknowns ({how} solve)",
                     hint="use a coarser volume mesh" + ("" if self.iterative else " or the iterative solver"),
                     limit_gb=memory_limit)
        self.force = dolfinx.fem.Constant(mesh, np.zeros(3, dtype=dolfinx.default_scalar_type))
        (u, p), (v, q) = ufl.TrialFunctions(self.W), ufl.TestFunctions(self.W)
        self.dx = cell_measure(mesh, degree)
        mu_c = dolfinx.fem.Constant(mesh, dolfinx.default_scalar_type(mu))
        a, L = stokes_brinkman_forms(u, p, v, q, mu_c, K_inv, self.force, self.dx)
        self.L = dolfinx.fem.form(L)
        self._coarse_forms = (K_inv, mu_c, solid)
        self.velocity_levels: tuple[PETSc.Mat, PETSc.Mat] | None = None
        try:
            self.reduction = periodic_reduction(self.W, box, solid)
            self._keep(self.reduction.R)
            self.R, self.fixed, self.percolates = self.reduction.R, self.reduction.held, self.reduction.percolates
            self.A = self._keep(reduced(dolfinx.fem.form(a), self.reduction))
            self.assembly_seconds = time.perf_counter() - t0
            self._solver(options)
        except BaseException:
            self.destroy()
            raise

    def _keep(self, obj):
        self._objects.append(obj)
        return obj

    def _solver(self, options: dict) -> None:
        t0 = time.perf_counter()
        if not self.iterative:
            self.direct = DirectSolver(self.comm, options, prefix="tfx_flow")
            self._objects.append(self.direct)
            self.direct.factor(self.A)
            self.ksp = self.direct.ksp
        else:
            self.ksp = self._keep(PETSc.KSP().create(self.comm))
            prefix = f"tfx_flow_{next(_serial)}_"
            self.ksp.setOptionsPrefix(prefix)
            with petsc_options(prefix, options):
                self.ksp.setOperators(self.A)
                pc = self.ksp.getPC()
                pc.setType("fieldsplit")
                velocity, pressure = (self._keep(PETSc.IS().createGeneral(rows.astype(PETSc.IntType), comm=self.comm))
                                      for rows in self.reduction.fields)
                pc.setFieldSplitIS(("u", velocity), ("p", pressure))
                self.ksp.setFromOptions()
                if options.get("fieldsplit_u_pc_type") == "mg":
                    self._velocity_coarse_level(pc)
                self.ksp.setUp()
                pc.setUpOnBlocks()  # the blocks' preconditioners (AMG) here, while their options are set
        self.setup_seconds = time.perf_counter() - t0
        self.iterations: list[int] = []

    def _velocity_coarse_level(self, pc: PETSc.PC) -> None:
        """The velocity block's p-multigrid: its P1 coarse level and prolongation (pmultigrid.py),
        given to the block's PCMG once the fieldsplit has made its blocks; velocity_levels: (P, A_1)."""
        pc.setUp()
        K_inv, mu_c, solid = self._coarse_forms
        P, A1 = velocity_coarse_level(self.W, K_inv, mu_c, self.dx, self.box, solid, self.reduction)
        self.velocity_levels = (self._keep(P), self._keep(A1))
        mg = pc.getFieldSplitSubKSP()[0].getPC()
        mg.setMGInterpolation(1, P)
        mg.getMGCoarseSolve().setOperators(A1)

    def solve(self, forces: np.ndarray) -> list[dolfinx.fem.Function]:
        """The velocity and pressure for each body force f [Pa/mm] (rows of `forces`), as Functions
        of the mixed space."""
        out = []
        for k, f in enumerate(np.atleast_2d(forces)):
            t0 = time.perf_counter()
            self.force.value[:] = f
            b = dolfinx.fem.petsc.assemble_vector(self.L)
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            rhs = self.R.createVecRight()
            self.R.multTranspose(b, rhs)
            first = rhs.getOwnershipRange()[0]
            rhs.getArray()[self.fixed - first] = 0.0
            x = rhs.duplicate()
            self.ksp.solve(rhs, x)
            self.iterations.append(self.ksp.getIterationNumber())
            reason = self.ksp.getConvergedReason()
            if reason <= 0:
                for obj in (b, rhs, x):
                    obj.destroy()
                raise SolverError(f"flow cell problem, load case {k + 1}: the solve failed (PETSc reason {reason})")
            w = dolfinx.fem.Function(self.W, name=f"flow_{k + 1}")
            self.R.mult(x, w.x.petsc_vec)
            w.x.scatter_forward()
            for obj in (b, rhs, x):
                obj.destroy()
            log.info("flow load case %d/%d: %.2f s", k + 1, len(np.atleast_2d(forces)), time.perf_counter() - t0)
            out.append(w)
        return out

    def mean_velocity(self, w: dolfinx.fem.Function) -> np.ndarray:
        """<u> over the box [mm/s] (collective)."""
        u = ufl.split(w)[0]
        total = [self.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(u[i] * self.dx)), op=MPI.SUM)
                 for i in range(3)]
        return np.array(total) / self.box.volume

    @property
    def dofs(self) -> int:
        return self.W.dofmap.index_map.size_global

    def destroy(self) -> None:
        for obj in reversed(self._objects):
            obj.destroy()
        self._objects = []
