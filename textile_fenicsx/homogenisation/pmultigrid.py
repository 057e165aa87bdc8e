"""The transfer of two-level p-multigrid: a degree-2 cell problem (P2 or Q2) with its degree-1
counterpart on the same mesh as the coarse level (cellproblem.CG_PMG).

A periodic P1 field is a periodic P2 field on the same mesh, so the prolongation is exact: the
reduced P1 vector is completed (each slave takes its master's value, the pinned block 0), then
interpolated into P2, whose slaves and pinned block are zeroed (the P2 system holds them decoupled):

    P = Z_2 I K_1.

Both degrees pin the same vertex (periodic.pin), so the P1 matrix dolfinx_mpc assembles is the
Galerkin product P^T A_2 P on the free dofs (tests/test_homogenise.py): the coarse level needs no
product of the large matrix, which took most of GAMG's setup on P2 (docs/homogenise.md).
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

import dolfinx.fem.petsc

__all__ = ["prolongation"]


def _completion(problem) -> PETSc.Mat:
    """K: the problem's reduced vector -> its full vector (a slave gets its masters' combination,
    the pinned block 0, every other dof itself). problem: a cellproblem.CellProblem."""
    V = problem.mpc.function_space
    imap, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    n, start = imap.size_local * bs, imap.local_range[0] * bs
    blocks = imap.local_to_global(np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32))
    offsets, masters = np.asarray(problem.mpc.masters.offsets), np.asarray(problem.mpc.masters.array)
    coefficients, _ = problem.mpc.coefficients()
    slaves = np.asarray(problem.mpc.slaves)
    slaves = slaves[slaves < n]
    counts = np.where(problem.constrained, 0, 1)
    counts[slaves] = offsets[slaves + 1] - offsets[slaves]
    indptr = np.concatenate([[0], np.cumsum(counts)]).astype(PETSc.IntType)
    columns = np.empty(indptr[-1], dtype=PETSc.IntType)
    values = np.ones(indptr[-1], dtype=PETSc.ScalarType)
    free = np.flatnonzero(~problem.constrained)
    columns[indptr[free]] = start + free
    for k in range(int(counts[slaves].max(initial=0))):  # the k-th master of every slave that has one
        s = slaves[counts[slaves] > k]
        local = masters[offsets[s] + k]
        columns[indptr[s] + k] = blocks[local // bs] * bs + local % bs
        values[indptr[s] + k] = coefficients[offsets[s] + k]
    K = PETSc.Mat().createAIJ(((n, None), (n, None)), csr=(indptr, columns, values), comm=V.mesh.comm)
    K.assemble()
    return K


def prolongation(coarse, fine) -> PETSc.Mat:
    """P = Z_2 I K_1 from the coarse problem's reduced vector to the fine one's (collective; the
    caller destroys it). coarse, fine: cellproblem.CellProblem of degree 1 and 2 on one mesh."""
    K = _completion(coarse)
    I = dolfinx.fem.petsc.interpolation_matrix(coarse.V, fine.V)
    I.assemble()
    try:
        P = I.matMult(K)
    finally:
        K.destroy()
        I.destroy()
    zero = P.createVecLeft()
    zero.getArray()[:] = np.where(fine.constrained, 0.0, 1.0)
    P.diagonalScale(L=zero)
    zero.destroy()
    return P
