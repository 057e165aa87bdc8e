"""One periodic cell problem, several load cases: the matrix built once, CG + GAMG, energies.

The unknown is the periodic fluctuation: dolfinx_mpc's constraint (periodic.py) keeps the masters,
puts an identity row on every slave and adds the slaves' contributions to their masters, so the
assembled system is P^T K P on the masters and a decoupled identity on the slaves (whose right-hand
side is 0). The fluctuation is defined up to a translation: one dof block is pinned to 0
(periodic.pin; its row and column become identity too). The load is consistent (it integrates to
zero against a translation), so the pin carries no reaction and changes no energy; a pinned
matrix is nonsingular, which an iterative solver and GAMG's coarse direct solve need no special
care for (a null space on the matrix would leave GAMG's coarsest matrix singular).

The effective tensor is the energy of the total field u_i = E_i.x + v_i,
    |Y| A_ij = <E_i, E_j> + v_i . f_j + v_j . f_i + v_i . K v_j,   f_j = -b_j,
with <E_i, E_j> = int E_i . D E_j dx (the Voigt part, given by the caller); it is symmetric by
construction and its error is quadratic in the solver's (the slave and pinned entries of v are
set to 0 after each solve, so this is exactly the energy of the discrete field P v).
"""

from __future__ import annotations

import itertools
import logging
import time

import dolfinx_mpc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
from textile_fenicsx.common.errors import SolverError
from textile_fenicsx.common.petsc import petsc_options
from textile_fenicsx.homogenisation.periodic import Box, periodic_constraint, pin
from textile_fenicsx.homogenisation.pmultigrid import prolongation

__all__ = ["CG_GAMG", "CG_PMG", "CellProblem", "cell_measure", "default_solver", "two_level"]

log = logging.getLogger(__name__)

# CG preconditioned by smoothed-aggregation AMG (GAMG) with the near-null space the caller gives
# (elasticity: the six rigid-body modes), Chebyshev smoothing with point-block Jacobi (the inverse of
# each node's 3 x 3 diagonal block; plain Jacobi for a scalar problem).
# The residual is measured unpreconditioned, so ksp_rtol is the reduction of ||b - A x||. The
# energy's error is quadratic in the solver's: on the bench's satin-like cell (100k P2 dofs, T300/
# epoxy) C moved by 1.8e-8 (of its largest entry) at rtol 1e-4, 1.6e-10 at 1e-5 and 1.9e-12 at 1e-6
# against rtol 1e-9, in 20, 25 and 31 iterations: 1e-5 keeps a factor 1e4 under the 1e-6 asked.
# Aggressive coarsening (square graph) on the first two levels instead of PETSc's one: the second
# level's coarse matrices (6 rigid-body modes a node, from P2) were nearly dense and their Galerkin
# products took most of the setup; on the 1.1 M-dof tet satin (2 ranks) the setup took 19 s
# instead of 38, with the same 33 iterations a load case. Point-block Jacobi instead of Jacobi
# (DOLFINx's elasticity demo) took 29-31 iterations there instead of 35 when profiled, 7.5 s a
# case instead of 8.5, and 27-37 against 29-38 in whole runs (2026-11-27; GAMG's aggregates vary
# from run to run); on the Q2 voxel satin 20 instead of 21. Tried and not kept: SOR (22
# iterations, 19 s a case), Chebyshev of degree 1 (56) and 3 (29 iterations, 10.5 s).
CG_GAMG = {
    "ksp_type": "cg",
    "ksp_norm_type": "unpreconditioned",
    "ksp_rtol": 1e-5,
    "ksp_atol": 0.0,
    "ksp_max_it": 2000,
    "pc_type": "gamg",
    "pc_gamg_type": "agg",
    "pc_gamg_agg_nsmooths": 1,
    "pc_gamg_threshold": 0.01,
    "pc_gamg_aggressive_coarsening": 2,
    "mg_levels_ksp_type": "chebyshev",
    "mg_levels_pc_type": "pbjacobi",
    "mg_levels_esteig_ksp_type": "cg",
}

# Degree 2 and up: two-level p-multigrid (pmultigrid.py). The P2 (Q2) level is smoothed as GAMG's
# levels are; the coarse level is the P1 (Q1) problem on the same mesh, solved by one V-cycle of
# CG_GAMG's GAMG. GAMG on P2 itself spent most of its setup on the Galerkin product of the large
# matrix (12 s of 20 on the tet satin, 2 ranks); P1's matrix is assembled instead, and exactly:
# on the corrected satin's tet mesh at 1.0 mm (0.9 M P2 dofs, 2 ranks) the setup took 4.4 s
# instead of 21.8 and a load case 25 iterations and 4.9 s instead of 32 and 8.6 s, C the same to
# 4e-11 (2026-11-27).
CG_PMG = {
    **{key: value for key, value in CG_GAMG.items() if key.startswith("ksp_")},
    "pc_type": "mg",
    "pc_mg_levels": 2,
    "pc_mg_galerkin": "none",
    **{key: value for key, value in CG_GAMG.items() if key.startswith("mg_levels_")},
    "mg_coarse_ksp_type": "preonly",
    **{"mg_coarse_" + key: value for key, value in CG_GAMG.items() if not key.startswith("ksp_")},
}


def two_level(options: dict | None) -> bool:
    """Whether the options ask p-multigrid (then the problem needs its degree-1 coarse level)."""
    return options is not None and options.get("pc_type") == "mg"


def default_solver(degree: int) -> dict:
    """The cell problems' PETSc options for Lagrange elements of `degree` (a fresh dict)."""
    return dict(CG_PMG if degree > 1 else CG_GAMG)


_serial = itertools.count()


def _parallelepipeds(mesh: dolfinx.mesh.Mesh, rtol: float = 1e-10) -> bool:
    """Whether every cell of a hexahedral mesh (on every rank) is a parallelepiped: its map from the
    reference cube is affine (no bilinear or trilinear term), as a voxel mesh's boxes are."""
    x = mesh.geometry.x[mesh.geometry.dofmap]  # (cells, 8, 3), DOLFINx's tensor-product order
    if mesh.geometry.cmap.degree != 1 or x.shape[1] != 8:
        return mesh.comm.allreduce(False, op=MPI.LAND)
    x0, x1, x2, x4 = x[:, 0], x[:, 1], x[:, 2], x[:, 4]
    affine = np.stack([x1 + x2 - x0, x1 + x4 - x0, x2 + x4 - x0, x1 + x2 + x4 - 2 * x0], axis=1)
    size = np.max(np.ptp(x, axis=1), initial=0.0)
    here = bool(np.all(np.abs(x[:, [3, 5, 6, 7]] - affine) <= rtol * max(size, 1e-300)))
    return mesh.comm.allreduce(here, op=MPI.LAND)


def cell_measure(mesh: dolfinx.mesh.Mesh, degree: int) -> ufl.Measure:
    """dx for the cell problems' forms (grad w . M grad v, M a DG0 coefficient, Lagrange of
    `degree`). On simplices UFL's estimate, 2 (degree - 1), is exact. On hexahedra UFL counts the
    non-affine map and asks 2 degree + 3 (Q2: 4 x 4 x 4 Gauss points); on parallelepipeds the
    integrand is a polynomial of degree 2 degree in each reference coordinate, which degree + 1
    Gauss points a direction integrate exactly (Q2: 27 points): that degree is asked there."""
    if mesh.topology.cell_type == dolfinx.mesh.CellType.hexahedron and _parallelepipeds(mesh):
        return ufl.dx(domain=mesh, metadata={"quadrature_degree": 2 * degree})
    return ufl.dx(domain=mesh)
_REASONS = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items() if not k.startswith("_")}


class CellProblem:
    """a(v, w) = L(w; load) on a periodic box for several values of the load constant.

    V: the fluctuation's space; a, L: UFL forms (L linear in `load`, a dolfinx.fem.Constant);
    near_null: arrays (owned dofs of V, blocked layout) spanning the operator's near-null space
    for GAMG, or None (GAMG's default, the constant); options: PETSc options (plain dict, written
    under a prefix of the problem's own and removed once the KSP is set up), or None for a coarse
    level (assembled, no solver); name: for messages; coarse: the same problem in degree 1 on the
    same mesh, the coarse level of the options' p-multigrid (CG_PMG), which this problem destroys.
    `destroy()` frees every PETSc object (call it in a finally).
    """

    def __init__(self, V, a, L, load, box: Box, options: dict | None, name: str, near_null=None,
                 coarse: CellProblem | None = None):
        self.name, self.load, self.V, self.coarse = name, load, V, coarse
        self._objects: list = [] if coarse is None else [coarse]
        try:
            t0 = time.perf_counter()
            self.mpc = periodic_constraint(V, box)
            self.bc = pin(V, box)
            self.constrained = self._constrained()
            self.a, self.L = dolfinx.fem.form(a), dolfinx.fem.form(L)
            self.A = self._keep(dolfinx_mpc.assemble_matrix(self.a, self.mpc, bcs=[self.bc]))
            self.A.setOption(PETSc.Mat.Option.SPD, True)
            if near_null is not None:
                self._near_null_space(near_null)
            self.operator = self._blocked(self.A)
            self.assembly_seconds: float = time.perf_counter() - t0
            if coarse is not None:
                self.assembly_seconds += coarse.assembly_seconds
            if options is not None:
                self._solver(options)
        except BaseException:
            self.destroy()
            raise

    def _keep(self, obj):
        self._objects.append(obj)
        return obj

    def _constrained(self) -> np.ndarray:
        """Owned dofs whose value is fixed (slaves, the pinned block)."""
        n = self.V.dofmap.index_map.size_local * self.V.dofmap.index_map_bs
        mask = np.zeros(n, dtype=bool)
        slaves = np.asarray(self.mpc.slaves)
        mask[slaves[slaves < n]] = True
        pinned = self.bc.dof_indices()[0]
        mask[pinned[pinned < n]] = True
        return mask

    def _blocked(self, A):
        """The operator CG and the smoothers apply: A itself, or for a vector space a copy in block
        CSR (BAIJ, one block per node). Its product costs about half of AIJ's on P2 elasticity
        (CG + GAMG on the 1.1 M-dof satin, 2 ranks: 11 s per load case instead of 20 s, the same
        iterations), for about 0.7 kB more per unknown. GAMG builds its hierarchy from A: it cannot
        make its graph from a BAIJ matrix."""
        if self.V.dofmap.index_map_bs == 1:
            return A
        B = self._keep(PETSc.Mat())
        A.convert(PETSc.Mat.Type.BAIJ, B)
        return B

    def _near_null_space(self, arrays) -> None:
        Vm = self.mpc.function_space
        vectors = [dolfinx.la.vector(Vm.dofmap.index_map, Vm.dofmap.index_map_bs) for _ in arrays]
        n = len(self.constrained)
        for vec, values in zip(vectors, arrays):
            vec.array[:n] = np.where(self.constrained, 0.0, values)
        dolfinx.la.orthonormalize(vectors)
        self._vectors = vectors  # the PETSc wrappers share their memory
        wrapped = [self._keep(dolfinx.la.create_petsc_vector_wrap(v)) for v in vectors]
        self.A.setNearNullSpace(self._keep(PETSc.NullSpace().create(vectors=wrapped, comm=self.V.mesh.comm)))

    def _solver(self, options: dict) -> None:
        t0 = time.perf_counter()
        self.ksp = self._keep(PETSc.KSP().create(self.V.mesh.comm))
        prefix = f"tfx_{self.name}_{next(_serial)}_"
        self.ksp.setOptionsPrefix(prefix)
        with petsc_options(prefix, options):
            self.ksp.setOperators(self.operator, self.A)
            self.ksp.setFromOptions()
            if two_level(options):
                self._coarse_level()
            self.ksp.setUp()  # GAMG reads its options and builds the hierarchy here
        self.pc_seconds = time.perf_counter() - t0

    def _coarse_level(self) -> None:
        """PCMG's two levels: this problem, smoothed; the degree-1 problem, solved by its options'
        mg_coarse_ KSP, through the exact prolongation (pmultigrid.py)."""
        if self.coarse is None:
            raise ValueError(f"{self.name} cell problem: p-multigrid (pc_type mg) needs degree 2 or more "
                             "(its coarse level is degree 1); use CG_GAMG for degree 1")
        pc = self.ksp.getPC()
        pc.setMGInterpolation(1, self._keep(prolongation(self.coarse, self)))
        pc.getMGCoarseSolve().setOperators(self.coarse.operator, self.coarse.A)

    def solve(self, loads, keep: bool = False) -> dict:
        """Solve for each load value (arrays for the load constant); returns {"energy": (n, n) array
        of v_i . f_j + v_j . f_i + v_i . K v_j, "iterations": [...], "seconds": [...]} and, with
        keep, "fluctuations": each load case's fluctuation as a Function (slaves filled in)."""
        xs, bs, its, secs = [], [], [], []
        for k, value in enumerate(loads):
            t0 = time.perf_counter()
            self.load.value[:] = value
            b = self._keep(dolfinx_mpc.assemble_vector(self.L, self.mpc))
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            dolfinx.fem.petsc.set_bc(b, [self.bc])
            x = self._keep(b.duplicate())
            x.set(0.0)
            self.ksp.solve(b, x)
            self._check(k, b)
            x.getArray()[self.constrained] = 0.0
            xs.append(x)
            bs.append(b)
            its.append(self.ksp.getIterationNumber())
            secs.append(time.perf_counter() - t0)
            log.info(f"{self.name} load case {k + 1}/{len(loads)}: {its[-1]} CG iterations, {secs[-1]:.2f} s")
        Kx = [self._keep(self.operator.createVecLeft()) for _ in xs]
        for x, y in zip(xs, Kx):
            self.operator.mult(x, y)
        n = len(xs)
        energy = np.array([[xs[i].dot(Kx[j]) - xs[i].dot(bs[j]) - xs[j].dot(bs[i]) for j in range(n)]
                           for i in range(n)])
        out = {"energy": energy, "iterations": its, "seconds": secs}
        if keep:
            out["fluctuations"] = [self._function(x, k) for k, x in enumerate(xs)]
        return out

    def _function(self, x, k: int) -> dolfinx.fem.Function:
        """The fluctuation of load case k as a Function of the constrained space (slave values set
        from their masters)."""
        v = dolfinx.fem.Function(self.mpc.function_space, name=f"{self.name}_fluctuation_{k + 1}")
        n = len(self.constrained)
        v.x.array[:n] = x.getArray()
        v.x.scatter_forward()
        self.mpc.backsubstitution(v)
        return v

    def _check(self, k: int, b) -> None:
        reason = self.ksp.getConvergedReason()
        if reason <= 0:
            residual = self.ksp.getResidualNorm()
            raise SolverError(f"{self.name} cell problem, load case {k + 1}: CG did not converge "
                              f"({_REASONS.get(reason, reason)}, reason {reason}) after "
                              f"{self.ksp.getIterationNumber()} iterations, residual {residual:.3g} against "
                              f"||b|| = {b.norm():.3g}")

    @property
    def dofs(self) -> int:
        """Unknowns of the space (slaves included)."""
        return self.V.dofmap.index_map.size_global * self.V.dofmap.index_map_bs

    def destroy(self) -> None:
        """Free the KSP, matrix, vectors and null spaces (collective)."""
        for obj in reversed(self._objects):
            obj.destroy()
        self._objects = []
