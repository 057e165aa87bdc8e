"""The periodic flow cell problem: Taylor-Hood velocity-pressure on the volume mesh, three load cases.

The unknowns live in one mixed space W = (P2)^3 x P1 (Q2 x Q1 on voxels): dolfinx_mpc 0.9's
constraints on a sub-space of a mixed space miss dofs (its issue 235), and its block assembly with
two constrained fields had a wrong sparsity pattern (issues 215/216), so the periodicity is applied
here by PETSc alone: the whole system is assembled without it, and reduced by R, the map from the
unknowns kept to every dof (R[i, i] = 1 for a dof kept, R[s, m] = 1 for a slave s on a + face and its
master m at its image, matched by location and component as homogenisation/periodic.py matches
them: every + coordinate wrapped at once, one master each, coefficient 1). The reduced matrix is
R^T A R, whose slave rows and columns are then the identity's, as are those of the dofs held at 0:
one pressure dof (the pressure is defined up to a constant), and where the yarns are solid, the
velocity of their cells (no-slip on their surfaces) and the pressure dofs that touch no pore.
The three load cases share one operator: it is factorised once (MUMPS LU; a saddle point).
"""

from __future__ import annotations

import logging
import time

import basix.ufl
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc
from scipy.spatial import cKDTree

import dolfinx
import dolfinx.fem.petsc
from textile_fenicsx.common import memory
from textile_fenicsx.common.errors import GeometryError, SolverError
from textile_fenicsx.flow.forms import stokes_brinkman_forms
from textile_fenicsx.homogenisation.cellproblem import cell_measure
from textile_fenicsx.homogenisation.periodic import Box, check_node_periodicity
from textile_fenicsx.plate.solver.linear import DIRECT_LU, DirectSolver

__all__ = ["DIRECT", "FlowCellProblem"]

log = logging.getLogger(__name__)

# A saddle point of a few hundred thousand unknowns: MUMPS' LU with its own pivoting (the plate
# solver's DIRECT_LU and DirectSolver: options under a prefix, removed once read)
DIRECT = DIRECT_LU


def _labelled_dofs(W: dolfinx.fem.FunctionSpace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every local dof of the mixed space W (owned, then ghosts): its W index, location and label
    (0, 1, 2: the velocity's components; 3: the pressure)."""
    n = W.dofmap.index_map.size_local + W.dofmap.index_map.num_ghosts
    points, labels = np.zeros((n, 3)), np.full(n, -1, np.int32)
    for field in (0, 1):
        V, dofs = W.sub(field).collapse()
        bs = V.dofmap.index_map_bs
        x = V.tabulate_dof_coordinates()
        dofs = np.asarray(dofs).reshape(-1, bs)
        for c in range(bs):
            points[dofs[:, c]] = x[: len(dofs)]
            labels[dofs[:, c]] = 3 * field + c
    return np.arange(n, dtype=np.int32), points, labels


class FlowCellProblem:
    """The Stokes-Brinkman cell (forms.py) of a DG0 inverse permeability K_inv [mm^-2] (0 in the
    pores), on the periodic box `box`. solid: a boolean per local cell (owned and ghost), True where
    the yarns are impermeable (no-slip on their surfaces), or None. mu: the viscosity [Pa s].
    memory_limit [GB]: refuse a problem whose direct solve would need more (None: what is available).
    `destroy()` frees the PETSc objects."""

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
        memory.check(memory.flow_bytes(self.dofs), what=f"the flow problem's {self.dofs} unknowns (direct solve)",
                     hint="use a coarser volume mesh", limit_gb=memory_limit)
        self.force = dolfinx.fem.Constant(mesh, np.zeros(3, dtype=dolfinx.default_scalar_type))
        (u, p), (v, q) = ufl.TrialFunctions(self.W), ufl.TestFunctions(self.W)
        self.dx = cell_measure(mesh, degree)
        a, L = stokes_brinkman_forms(u, p, v, q, dolfinx.fem.Constant(mesh, dolfinx.default_scalar_type(mu)),
                                     K_inv, self.force, self.dx)
        self.L = dolfinx.fem.form(L)
        try:
            A = self._keep(dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(a)))
            A.assemble()
            self.R, self.fixed = self._reduction(solid)
            self.A = self._keep(A.PtAP(self.R))
            # the held rows of R^T A R are empty (a slave's) or not: give each a diagonal entry (merged in
            # by axpy with a diagonal of the held rows; MPIAIJ's zeroRowsColumns needs the entry, and
            # inserting them one at a time into the assembled matrix took 3 ms each), then make them
            # the identity's
            self.A.axpy(1.0, self._keep(self._diagonal(self.fixed)), PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
            self.A.zeroRowsColumns(self.fixed, 1.0)
            self.assembly_seconds = time.perf_counter() - t0
            self._solver(options or DIRECT)
        except BaseException:
            self.destroy()
            raise

    def _keep(self, obj):
        self._objects.append(obj)
        return obj

    def _reduction(self, solid: np.ndarray | None) -> tuple[PETSc.Mat, np.ndarray]:
        """R (module docstring) and the owned rows held at 0 (global indices), collective."""
        comm, box = self.comm, self.box
        imap = self.W.dofmap.index_map
        owned = imap.size_local
        local, points, labels = _labelled_dofs(self.W)
        glob = imap.local_to_global(local).astype(np.int64)
        lo, hi = np.asarray(box.lo), np.asarray(box.hi)
        on_face = np.any((np.abs(points - lo) < box.tol) | (np.abs(points - hi) < box.tol), axis=1)
        mine = np.flatnonzero(on_face[:owned])
        face = [np.concatenate(x) for x in zip(*comm.allgather((points[mine], labels[mine], glob[mine])))]
        plus = np.abs(points[:owned] - hi) < box.tol
        slaves = np.flatnonzero(np.any(plus, axis=1))
        masters = np.empty(len(slaves), np.int64)
        wrapped = points[slaves] - plus[slaves] * np.asarray(box.size)
        for label in range(4):
            here = face[1] == label
            check_node_periodicity(face[0][here], box, "the flow problem's dof locations")
            mine_l = labels[slaves] == label
            if not np.any(mine_l):
                continue
            distance, nearest = cKDTree(face[0][here]).query(wrapped[mine_l], distance_upper_bound=box.tol)
            if not np.all(np.isfinite(distance)):
                raise GeometryError("flow problem: a + face dof has no dof of its kind at its image")
            masters[mine_l] = face[2][here][nearest]
        columns = glob[:owned].copy()
        columns[slaves] = masters
        n_global = imap.size_global
        R = self._keep(PETSc.Mat().createAIJ(((owned, n_global), (owned, n_global)),
                                             csr=(np.arange(owned + 1, dtype=PETSc.IntType),
                                                  columns.astype(PETSc.IntType), np.ones(owned)),
                                             comm=comm))
        held = np.zeros(owned, bool)
        held[slaves] = True
        pressure = labels[:owned] == 3
        live = np.ones(owned, bool)  # pressure dofs that touch a pore
        if solid is not None:
            in_solid, in_fluid = self._touching(solid, glob, slaves, masters)
            held |= in_solid & (labels[:owned] < 3)  # no-slip: the velocity of the solid's cells
            live = in_fluid
            held |= pressure & ~in_fluid
        candidates = glob[:owned][pressure & live & ~held]
        first = comm.allreduce(int(candidates.min()) if len(candidates) else np.iinfo(np.int64).max, op=MPI.MIN)
        if first == np.iinfo(np.int64).max:
            raise GeometryError("flow problem: no pore to hold the fluid (every cell is solid)")
        held |= glob[:owned] == first  # the pressure's constant
        self.slaves = comm.allreduce(len(slaves), op=MPI.SUM)
        return R, glob[:owned][held].astype(PETSc.IntType)

    def _diagonal(self, rows: np.ndarray) -> PETSc.Mat:
        """A matrix of the reduced system's layout with a 1 on the diagonal at the (owned, global)
        rows given and nothing elsewhere."""
        first, end = self.A.getOwnershipRange()
        n, N = end - first, self.A.getSize()[0]
        counts = np.zeros(n + 1, dtype=PETSc.IntType)
        counts[rows - first + 1] = 1
        return PETSc.Mat().createAIJ(((n, N), (n, N)), csr=(np.cumsum(counts).astype(PETSc.IntType),
                                                            np.sort(rows).astype(PETSc.IntType),
                                                            np.ones(len(rows))), comm=self.comm)

    def _touching(self, solid: np.ndarray, glob: np.ndarray, slaves: np.ndarray,
                  masters: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whether each owned dof, or a periodic image of it, belongs to a solid cell and to a pore
        cell (collective: the cells of other ranks and across the box's faces count)."""
        imap = self.W.dofmap.index_map
        owned = imap.size_local
        cells = np.asarray(self.W.dofmap.list)
        flags = []
        for chosen in (solid, ~solid):
            vec = dolfinx.la.vector(imap, 1)
            vec.array[np.unique(cells[chosen])] = 1.0
            vec.scatter_reverse(dolfinx.la.InsertMode.add)
            here = vec.array[:owned] > 0
            seen = np.concatenate(self.comm.allgather(masters[here[slaves]]))  # a slave's own cells
            flags.append(here | np.isin(glob[:owned], seen))
        return flags[0], flags[1]

    def _solver(self, options: dict) -> None:
        t0 = time.perf_counter()
        self.direct = DirectSolver(self.comm, options, prefix="tfx_flow")
        self._objects.append(self.direct)
        self.direct.factor(self.A)
        self.ksp = self.direct.ksp
        self.setup_seconds = time.perf_counter() - t0

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
