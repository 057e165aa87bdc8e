"""The Newton systems of yarns that flatten, solved in each node's mid-height and thickness change
(DESIGN.md 5a, 6).

Where the yarns flatten, the unknowns are each node's bottom and top heights (x_b, x_t), so that
every constraint reads one unknown of each yarn (g0 + x_i - x_j >= 0). The plates bend with the
mean w = (x_b + x_t) / 2, so their matrix A appears in all four blocks of a node pair, A/4 in
each, and the direct solver's factor carries it four times. In w and dt = x_t - x_b it appears
once. With x = T y, y = (w, dt) per node (w in the bottom's place, dt in the top's),
    x_b = w - dt/2,   x_t = w + dt/2,
the Newton system K dx = r is solved as (T^T K T) dy = T^T r, dx = T dy. The plates' entries of
T^T K T in (w, dt) and (dt, dt) cancel to exactly 0 (four equal terms, A/8 or A/16, with signs:
sums of one number scaled by powers of two) and are left out of the pattern. T^T K T is congruent
to K: the same inertia and null pivots, so the factorisation's checks read the same. The interior point's unknowns,
constraints and residuals stay in (x_b, x_t); only the linear solves change basis.
Measured on satin4 (seed 0.5, a Newton matrix of the compaction): the factor's entries 5.3 M ->
2.4 M, its flops 2.65e9 -> 0.48e9, a factorisation 0.144 -> 0.049 s.
"""

import numpy as np
import scipy.sparse
from petsc4py import PETSc

from textile_fenicsx.plate.solver.numbering import Periodicity
from textile_fenicsx.plate.solver.pattern import FixedPattern

__all__ = ["MidAndThickness"]


class MidAndThickness:
    """The map between the problem's Newton matrices in (x_b, x_t) (a frozen FixedPattern's
    values) and their form in (w, dt) with its own, smaller pattern; and T, T^T on vectors."""

    def __init__(self, pattern: FixedPattern, numbering: Periodicity):
        self.comm, self.start, self.n_local, self.n = pattern.comm, pattern.start, pattern.n_local, pattern.n_cols
        nnz, counts = len(pattern.indices), np.diff(pattern.indptr)
        own = np.arange(self.start, self.start + self.n_local, dtype=np.int64)
        b, t, s = numbering.surface_pairs(own)  # per row, then per entry of the pattern
        rb, rt, rs = (np.repeat(a, counts) for a in (b, t, s))
        cb, ct, cs = numbering.surface_pairs(pattern.indices)
        # entry (r, c) of K adds T[r, i] K[r, c] T[c, j] at (i, j) for i in {w_r, dt_r}, j in {w_c, dt_c}:
        # the four quadrants of its node pair's block, found once per block (nnz keys sorted, not 4 nnz)
        blocks, first, inverse = np.unique(rb * np.int64(self.n) + cb, return_index=True, return_inverse=True)
        keys = np.concatenate([(r[first] - self.start) * np.int64(self.n) + c[first]
                               for r, c in ((rb, cb), (rb, ct), (rt, cb), (rt, ct))])
        nb, small = len(blocks), np.int32 if 4 * nnz < 2**31 else np.int64  # (indices into 4 nnz at most)
        del blocks, first, cb, ct
        order = np.argsort(keys)
        unique, rank = keys[order], np.empty(len(keys), small)
        rank[order] = np.arange(len(keys), dtype=small)
        del keys, order
        # M^T, one row per entry of K: its four targets in (w, dt), and T's coefficients there (no
        # triplets to sort: each K entry's row holds its four terms, those landing in entries that
        # are exact zeros left out)
        target = np.stack([rank[q * nb + inverse] for q in range(4)], axis=1)
        coefficients = np.stack([np.ones(nnz), cs / 2, rs / 2, rs * cs / 4], axis=1)
        del rank, inverse, rb, rt, rs, cs
        # an entry of (w, dt) is kept where the constant part leaves a value or a variable one can
        # arrive (contact weights, the compaction law's Hessian); the diagonal always
        touched = np.zeros(nnz, bool)
        touched[pattern.positions] = True
        keep = (np.bincount(target.ravel(), (coefficients * pattern.base[:, None]).ravel(), len(unique)) != 0) \
            | (np.bincount(target[touched].ravel(), minlength=len(unique)) > 0) \
            | (unique // self.n + self.start == unique % self.n)
        on = keep[target]
        renumbered = (np.cumsum(keep) - 1).astype(small)
        indptr = np.concatenate([[0], np.cumsum(on.sum(axis=1))]).astype(small)
        MT = scipy.sparse.csr_matrix((coefficients[on], renumbered[target[on]], indptr), shape=(nnz, int(keep.sum())))
        self.M = MT.T.tocsr()  # (each row's terms in the order of the pattern, as they are added)
        unique = unique[keep]
        row_starts = np.arange(self.n_local + 1, dtype=np.int64) * self.n
        self.indptr = np.searchsorted(unique, row_starts).astype(PETSc.IntType)
        self.indices = (unique % self.n).astype(PETSc.IntType)
        self.bottom, self.top = (own[s < 0] - self.start), (t[s < 0] - self.start)
        assert np.array_equal(b[s < 0], own[s < 0])

    def matrix(self, values: np.ndarray) -> PETSc.Mat:
        """A new AIJ matrix in (w, dt) from the values of a Newton matrix in (x_b, x_t)."""
        A = PETSc.Mat().createAIJ(((self.n_local, self.n),) * 2, comm=self.comm)
        A.setPreallocationCSR((self.indptr, self.indices, self.M @ values))
        A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        A.assemble()
        return A

    def fill(self, A: PETSc.Mat, values: np.ndarray) -> None:
        """Put T^T K T into A (made by `matrix`), K given by its values in the (x_b, x_t) pattern."""
        A.setValuesCSR(self.indptr, self.indices, self.M @ values, addv=PETSc.InsertMode.INSERT_VALUES)
        A.assemble()

    def transpose(self, r: PETSc.Vec, out: PETSc.Vec) -> None:
        """out = T^T r: (r_b + r_t, (r_t - r_b) / 2) at each node (local)."""
        rv, ov = r.getArray(readonly=True), out.getArray()
        ov[self.bottom] = rv[self.bottom] + rv[self.top]
        ov[self.top] = 0.5 * (rv[self.top] - rv[self.bottom])

    def apply(self, y: PETSc.Vec, out: PETSc.Vec) -> None:
        """out = T y: (w - dt/2, w + dt/2) at each node (local)."""
        yv, ov = y.getArray(readonly=True), out.getArray()
        w, dt = yv[self.bottom].copy(), yv[self.top].copy()
        ov[self.bottom] = w - 0.5 * dt
        ov[self.top] = w + 0.5 * dt
