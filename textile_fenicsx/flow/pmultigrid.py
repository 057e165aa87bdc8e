"""The coarse level of the velocity block's two-level p-multigrid (problem.ITERATIVE): the P1
(Q1) velocity on the same mesh as the P2 (Q2) velocity of the Taylor-Hood problem.

A periodic P1 velocity is a periodic P2 velocity, so the prolongation from the P1 velocity's
reduced vector to the rows of the fieldsplit's velocity block is exact:

    P = Z S I R_1

R_1 completes the P1 vector (a slave on a + face takes its master's value: reduction.py's R on the
P1 velocity); I interpolates P1 into the collapsed P2 velocity space (DOLFINx's
interpolation_matrix); S puts each owned P2 dof at its row of the velocity block (the rank's
owned velocity rows of the mixed space, ascending: the fieldsplit's index set); Z zeroes the held
rows (slaves, and with solid yarns the velocity of their cells) and the held coarse columns.

The coarse operator is the P1 velocity's own matrix R_1^T A_1 R_1 (the viscous and drag terms;
the pressure has no part in the velocity block), held at the P1 dofs of solid cells and their
periodic images. It is the Galerkin product P^T A_uu P on the coarse dofs left, with no product
of the large P2 block: a coarse field 0 at the held vertices interpolates to 0 at every P2 dof of a
solid cell (those are combinations of the cell's own vertices), so Z changes nothing there, and
A_uu is R^T A R on the velocity (tests/test_flow.py checks it).
"""

from __future__ import annotations

import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
from textile_fenicsx.flow.forms import brinkman_drag, viscous
from textile_fenicsx.flow.reduction import Reduction, images, reduced, touching
from textile_fenicsx.homogenisation.periodic import Box

__all__ = ["velocity_coarse_level"]


def _coarse_reduction(V1: dolfinx.fem.FunctionSpace, box: Box, solid: np.ndarray | None) -> Reduction:
    """The P1 velocity's reduction (reduction.py's, per node, the three components alike): R_1
    and its held rows, the slaves and where the yarns are solid the nodes of their cells."""
    comm = V1.mesh.comm
    imap, bs = V1.dofmap.index_map, V1.dofmap.index_map_bs
    owned = imap.size_local
    glob = imap.local_to_global(np.arange(owned + imap.num_ghosts, dtype=np.int32)).astype(np.int64)
    points = V1.tabulate_dof_coordinates()
    slaves, masters, _ = images(comm, points, np.zeros(len(glob), np.int32), glob, owned, box)
    held = np.zeros(owned, bool)
    held[slaves] = True
    if solid is not None:
        held |= touching(V1, solid, glob, slaves, masters)[0]
    nodes = glob[:owned].copy()
    nodes[slaves] = masters
    component = np.arange(bs)
    columns = (bs * nodes[:, None] + component).ravel()
    n, N = bs * owned, bs * imap.size_global
    R1 = PETSc.Mat().createAIJ(((n, N), (n, N)), csr=(np.arange(n + 1, dtype=PETSc.IntType),
                                                      columns.astype(PETSc.IntType), np.ones(n)), comm=comm)
    rows = (bs * glob[:owned][:, None] + component).ravel()
    return Reduction(R1, rows[np.repeat(held, bs)].astype(PETSc.IntType), (rows, rows[:0]), np.ones(3, bool),
                     comm.allreduce(len(slaves), op=MPI.SUM) * bs)


def _velocity_space(W: dolfinx.fem.FunctionSpace) -> tuple[dolfinx.fem.FunctionSpace, np.ndarray]:
    """The mixed space's velocity as a space of its own, and the dof of W of each of its local dofs
    (blocked: 3 a node). What W.sub(0).collapse() gives, from the cells' dofs (collapsing took 6.5 s
    on the satin's 0.3 mm Q2 voxels, reduction.py): each component of the velocity sub-space lists
    a cell's dofs in the order of the blocked space's nodes, the same element."""
    velocity = W.sub(0)
    dim = velocity.ufl_element().reference_value_shape[0]
    V = dolfinx.fem.functionspace(W.mesh, ("Lagrange", velocity.ufl_element().degree, (dim,)))
    nodes = np.asarray(V.dofmap.list)
    to_W = np.full(dim * (V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts), -1, np.int64)
    for c in range(dim):
        to_W[dim * nodes + c] = np.asarray(velocity.sub(c).dofmap.list)
    return V, to_W


def _rows_of_split(W: dolfinx.fem.FunctionSpace, to_W: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """S: the row in the velocity block (local to the rank) of each owned dof of the velocity's own
    space, from its dof of W (to_W) and the owned velocity rows of W (global, ascending). Both
    spaces own a dof where its mesh entity is owned: a permutation of the rank's rows, checked."""
    local = velocity - W.dofmap.index_map.local_range[0]
    position = np.searchsorted(local, to_W)
    if (len(local) != len(to_W) or np.any(position >= len(local))
            or not np.array_equal(local[np.minimum(position, len(local) - 1)], to_W)):
        raise RuntimeError("flow p-multigrid: the velocity space's owned dofs are not W's owned velocity rows")
    return position


def velocity_coarse_level(W: dolfinx.fem.FunctionSpace, K_inv: dolfinx.fem.Function, mu: dolfinx.fem.Constant,
                          dx: ufl.Measure, box: Box, solid: np.ndarray | None,
                          reduction: Reduction) -> tuple[PETSc.Mat, PETSc.Mat]:
    """(P, A_1): the prolongation from the P1 velocity's reduced vector to the velocity block's rows
    (reduction: the mixed space's, whose fields[0] are the block's rows), and the coarse operator
    (module docstring; collective; the caller destroys both)."""
    mesh = W.mesh
    V1 = dolfinx.fem.functionspace(mesh, ("Lagrange", 1, (mesh.geometry.dim,)))
    coarse = _coarse_reduction(V1, box, solid)
    try:
        u, v = ufl.TrialFunction(V1), ufl.TestFunction(V1)
        A1 = reduced(dolfinx.fem.form((viscous(mu, u, v) + brinkman_drag(mu, K_inv, u, v)) * dx), coarse)
        V2, to_W = _velocity_space(W)
        I = dolfinx.fem.petsc.interpolation_matrix(V1, V2)
        I.assemble()
        IR = I.matMult(coarse.R)
        I.destroy()
        indptr, columns, values = IR.getValuesCSR()
        IR.destroy()
    finally:
        coarse.R.destroy()
    n = len(indptr) - 1
    velocity = reduction.fields[0]
    try:
        position = _rows_of_split(W, to_W[:n], velocity)
    except RuntimeError:
        A1.destroy()
        raise
    order = np.empty(n, np.int64)
    order[position] = np.arange(n)  # the block's row k is IR's row order[k]
    counts = np.diff(indptr)[order]
    start = np.concatenate([[0], np.cumsum(counts)])
    take = np.repeat(indptr[order] - start[:-1], counts) + np.arange(start[-1])
    comm = mesh.comm
    P = PETSc.Mat().createAIJ(((n, comm.allreduce(n, op=MPI.SUM)), (A1.getLocalSize()[0], A1.getSize()[0])),
                              csr=(start.astype(PETSc.IntType), columns[take].astype(PETSc.IntType), values[take]),
                              comm=comm)
    fine, kept = P.createVecLeft(), P.createVecRight()
    fine.getArray()[:] = np.where(np.isin(velocity, reduction.held), 0.0, 1.0)
    kept.set(1.0)
    kept.getArray()[coarse.held - kept.getOwnershipRange()[0]] = 0.0
    P.diagonalScale(L=fine, R=kept)
    fine.destroy()
    kept.destroy()
    return P, A1
