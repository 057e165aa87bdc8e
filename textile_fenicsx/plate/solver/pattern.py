"""The combined matrix as one AIJ matrix whose CSR pattern is fixed once (DESIGN.md 6: reuse the
symbolic factorisation across contact steps).

Triplets (row, column, value) may be given on any rank: each goes to its row's owner and repeated
entries are summed. Constant triplets (plates, pin) come yarn by yarn (`add_fixed`, collective) and
are compressed as they come; `freeze` then fixes the pattern with the variable triplets' (row,
column) (contact), after which `values(v)` gives the constant part plus these values in the
pattern's order, and `matrix(v)` a PETSc matrix with them. The entries are held as int64 keys
(row-major), never as big triplet arrays (they were the memory peak before the solve on large
coupons).
"""

import numpy as np
import scipy.sparse
from mpi4py import MPI
from petsc4py import PETSc

__all__ = ["FixedPattern"]


class FixedPattern:
    """The pattern of a square matrix over n unknowns, rows [start, start + n_local) on this rank."""

    def __init__(self, comm: MPI.Comm, start: int, n_local: int):
        self.comm, self.start, self.n_local = comm, start, n_local
        self.starts = np.array(comm.allgather(start))
        self.n_cols = comm.allreduce(n_local, op=MPI.SUM)
        self._fixed: list = []  # compressed (local row, column, value) pieces; None once frozen
        self.frozen = False

    def add_fixed(self, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray) -> None:
        """Constant entries (collective)."""
        if self.frozen:
            raise RuntimeError("FixedPattern: add_fixed after freeze")
        plan = self._plan(np.asarray(rows, np.int64))
        A = self._csr(*(self._route(plan, np.asarray(a, dt)) for a, dt in
                        ((rows, np.int64), (cols, np.int64), (vals, np.float64)))).tocoo()
        self._fixed.append((self._keys(A.row, A.col), A.data))

    def freeze(self, rows: np.ndarray, cols: np.ndarray) -> None:
        """Fix the pattern: the constant entries and these (row, column) of the variable values.
        Every entry is one int64 key, local row x columns + column; the pattern is the sorted
        union of the keys (about half the memory of summing triplets into a CSR)."""
        self.plan = self._plan(np.asarray(rows, np.int64))
        variable = self._keys(self._route(self.plan, np.asarray(rows, np.int64)) - self.start,
                              self._route(self.plan, np.asarray(cols, np.int64)))
        empty = (np.zeros(0, np.int64),) * 2
        fixed, fixed_values = (np.concatenate(a) for a in zip(*self._fixed)) if self._fixed else empty
        self._fixed, self.frozen = None, True  # type: ignore[assignment]  # freed: add_fixed refuses
        keys = np.concatenate([fixed, variable])
        keys.sort()
        keys = keys[np.concatenate(([True], keys[1:] != keys[:-1]))] if len(keys) else keys
        # the constant part in the pattern's order (repeated entries summed), and where each
        # variable value goes
        self.base = np.bincount(np.searchsorted(keys, fixed), weights=fixed_values, minlength=len(keys))
        del fixed, fixed_values
        small = np.int32 if len(keys) < 2**31 else np.int64
        self.positions = np.searchsorted(keys, variable).astype(small)
        del variable
        n = np.int64(self.n_cols)
        self.indptr = np.searchsorted(keys, np.arange(self.n_local + 1, dtype=np.int64) * n).astype(PETSc.IntType)
        self.indices = (keys % n).astype(PETSc.IntType)

    def values(self, variable: np.ndarray | None = None) -> np.ndarray:
        """Summed values (constant part + the variable values, given in freeze's order, on the rank
        that gave them) in the order of (indptr, indices)."""
        if variable is None:
            return self.base.astype(PETSc.ScalarType)
        v = self._route(self.plan, np.asarray(variable, np.float64))
        out = np.bincount(self.positions, weights=v, minlength=len(self.indices)).astype(np.float64, copy=False)
        out += self.base  # in place: on a coupon each array of this size is 0.2 GB per rank
        return out.astype(PETSc.ScalarType, copy=False)

    def absorb(self, variable: np.ndarray) -> None:
        """Make variable values (in freeze's order) part of the constant part for good."""
        self.base = self.values(variable).astype(np.float64, copy=False)

    def matrix(self) -> PETSc.Mat:
        """A new symmetric AIJ matrix with this pattern and the constant values."""
        A = PETSc.Mat().createAIJ(((self.n_local, self.n_cols),) * 2, comm=self.comm)
        A.setPreallocationCSR((self.indptr, self.indices, self.values()))
        A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        A.assemble()
        return A

    def fill(self, A: PETSc.Mat, variable: np.ndarray | None, pin: int | None = None) -> None:
        """Put constant + variable values into A (made by `matrix`); with `pin`, that unknown's row
        and column are those of the identity (the unknown keeps its value: a Dirichlet condition
        that leaves the matrix symmetric)."""
        values = self.values(variable)
        if pin is not None:
            line, diagonal = self._pin_positions(pin)
            values[line] = 0.0
            values[diagonal] = 1.0
        A.setValuesCSR(self.indptr, self.indices, values, addv=PETSc.InsertMode.INSERT_VALUES)
        A.assemble()

    def _pin_positions(self, pin: int) -> tuple[np.ndarray, np.ndarray]:
        """Positions (in the values' order) of row and column `pin`, and of its diagonal entry;
        found once."""
        if getattr(self, "_pin", (None,))[0] != pin:
            rows = self.start + np.repeat(np.arange(self.n_local), np.diff(self.indptr))
            line = np.flatnonzero((rows == pin) | (self.indices == pin))
            self._pin = (pin, line, line[rows[line] == self.indices[line]])
        return self._pin[1], self._pin[2]

    def _keys(self, local_rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(local row, column) as one sortable int64, row-major."""
        return np.asarray(local_rows, np.int64) * np.int64(self.n_cols) + np.asarray(cols, np.int64)

    def _csr(self, rows, cols, vals) -> scipy.sparse.csr_matrix:
        """A local-rows CSR of owned-row triplets, repeated entries summed, zeros kept."""
        return scipy.sparse.coo_matrix((vals, (rows - self.start, cols)), shape=(self.n_local, self.n_cols)).tocsr()

    def _plan(self, rows: np.ndarray):
        """How to send entries to their rows' owners: the order that groups them by owner (None
        on one rank), and the counts sent to and received from each rank."""
        if self.comm.size == 1:
            return None, np.array([len(rows)], np.int64), np.array([len(rows)], np.int64)
        owner = np.searchsorted(self.starts, rows, side="right") - 1
        order = np.argsort(owner, kind="stable").astype(np.int32 if len(rows) < 2**31 else np.int64)
        send = np.bincount(owner, minlength=self.comm.size).astype(np.int64)
        recv = np.array(self.comm.alltoall(send.tolist()), dtype=np.int64)
        return order, send, recv

    def _route(self, plan, data: np.ndarray) -> np.ndarray:
        order, send, recv = plan
        if order is None:
            return data
        data = data[order]
        out = np.empty(int(recv.sum()), dtype=data.dtype)
        sd = np.concatenate(([0], np.cumsum(send)[:-1]))
        rd = np.concatenate(([0], np.cumsum(recv)[:-1]))
        self.comm.Alltoallv([data, (send, sd)], [out, (recv, rd)])
        return out
