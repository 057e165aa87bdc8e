"""Plate + tension + contact solve of all yarns at once (DESIGN.md sections 5, 6 and 9).

Unknowns: one displacement field w_i (P2) per yarn on its footprint, z_i = z0_i + w_i. The energy

    sum_i [ 1/2 a_b(z_i, z_i) + 1/2 sigma1 |d . grad z_i|^2 ] + sum_(u,l) 1/2 k(g) g^2

is quadratic at fixed contact stiffness k, so each active-set step is one linear solve:
- each yarn's bending + tension matrix A_i is assembled on its submesh (real cells, and facets that
  touch a real cell: the ghost strip's copies give the periodic seam its interior-penalty terms);
- periodicity: every dof on the seam or in the strip is a slave of its image inside the cell; a
  sparse map R_i (yarn dofs -> unknowns, one 1 per row) applies it, K = sum R_i^T A_i R_i;
- contact: for each adjacent pair (upper u, lower l) the matrix M_p = k(g) u v on u's overlap cells
  and the map T_p (unknowns -> w_u - w_l at u's overlap dofs, exact point correspondence) add
  T_p^T M_p T_p; T_p is never stored as a matrix: each entry of M_p goes to four places of K, and
  the gaps come from one gather of the unknowns the overlaps need (a pair's data live on its
  overlap only: per-pair whole-yarn objects cost gigabytes on coupons with a thousand pairs);
- the common vertical translation is removed as a multiplier on the area-weighted mean of all w
  would remove it, but sparsely: net load spread over the area, one unknown pinned, the solution
  shifted to zero mean (independent of numbering and partition);
- K is one matrix whose CSR pattern is built once from triplets (plates, pin, contact pairs):
  each step only recomputes the contact values; MUMPS LDL^T (symmetric) on it, whose sparsity is
  fixed, so later steps refactorise numerically only.
The contact state (the sign of g - lam/Ec at the contact forms' quadrature points, which alone
decide the matrix) is iterated until none changes: each step is the Newton step of the convex
energy at the current states, halved until the energy falls (undamped, the active set cycled
at hard penalties, Ec >= 1e6); a cap and a cycle check (a repeated state without a fall of
energy) stop it. The augmented-Lagrangian option adds Uzawa updates of a contact
pressure until the penetration is below a tolerance that does not depend on Ec.
"""

import hashlib
import time
from dataclasses import dataclass, field

import basix
import numpy as np
import scipy.sparse
import ufl
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
from textile_fenicsx.errors import TextileError, check_positive
from textile_fenicsx.forms import c0ip_bending, contact_energy, contact_mass, contact_pressure, foundation, load, tension
from textile_fenicsx.meshes.midsurface import REAL, MidSurfaces
from textile_fenicsx.meshes.projected import release_freed_memory
from textile_fenicsx.solvers import DIRECT_LDLT, SolverError


@dataclass(frozen=True)
class PlateParameters:
    """Stiffnesses of the yarn plates (TexGen's defaults, which the paper used).

    Db1, Db2: bending stiffness along and across the fibre [N mm]; Db12: twisting stiffness [N mm]
    (default (Db1 + Db2) / 4); sigma1: fibre tension [N/mm]; Ec, Et: contact stiffness where yarns
    penetrate and where they are apart [N/mm^3]; alpha: interior-penalty factor [-]. Only ratios
    matter for the geometry.
    """

    Db1: float = 1.0
    Db2: float = 1.0
    Db12: float | None = None
    sigma1: float = 1.0
    Ec: float = 1e3
    Et: float = 1e-4
    alpha: float = 8.0

    def __post_init__(self):
        for name in ("Db1", "Db2", "sigma1", "Et"):
            check_positive(name, getattr(self, name), allow_zero=True)
        check_positive("Ec", self.Ec)
        check_positive("alpha", self.alpha)
        if self.Db12 is None:
            object.__setattr__(self, "Db12", (self.Db1 + self.Db2) / 4)
        check_positive("Db12", self.Db12, allow_zero=True)


@dataclass(frozen=True)
class SolverOptions:
    """How to iterate. method: "penalty" (the paper's) or "augmented" (Uzawa updates of a contact
    pressure until the penetration is below penetration_tol [mm], whatever Ec: contact becomes hard,
    with augmented_penalty [N/mm^3] as the algorithm's own penalty). max_iterations: cap on
    active-set steps per solve; max_updates: cap on augmented-Lagrangian updates. petsc: options of
    the linear solve."""

    method: str = "penalty"
    max_iterations: int = 60
    max_updates: int = 30
    penetration_tol: float = 1e-4
    augmented_penalty: float = 1e5
    petsc: dict = field(default_factory=lambda: dict(DIRECT_LDLT))

    def __post_init__(self):
        if self.method not in ("penalty", "augmented"):
            raise TextileError(f"solver method must be 'penalty' or 'augmented', got {self.method!r}")
        if int(self.max_iterations) < 1 or int(self.max_updates) < 1:
            raise TextileError("max_iterations and max_updates must be >= 1")
        check_positive("penetration_tol", self.penetration_tol)


@dataclass
class Solution:
    """Displacements per yarn (Functions on each mid-surface's P2 space) and how they were found."""

    w: list
    iterations: int
    updates: int
    history: list
    max_penetration: float          # largest -g at overlap dofs [mm]
    converged: bool
    times: dict
    penetration_quadrature: float = 0.0  # largest -g where the energy integrates it [mm]
    penetration_volume: float = 0.0      # integral of max(0, -g) over the overlaps [mm^3]
    reason: str = ""                     # why the iteration stopped (converged, or what failed)


# --- numbering ----------------------------------------------------------------------------

class _Layout:
    """Global numbering of the unknowns: per rank, per yarn, the owned master dofs; then one
    multiplier (owned by the last rank)."""

    def __init__(self, ms: MidSurfaces):
        V, comm = ms.V, ms.V.mesh.comm
        imap = V.dofmap.index_map
        self.comm = comm
        parent_global = imap.local_to_global(np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32))
        images = {}
        for y, pairs in zip(ms.yarns, ms.periodic):
            order = np.argsort(pairs[:, 0])
            images[y.yarn] = (pairs[order, 0], pairs[order, 1])
        self.images = images
        # each yarn dof is counted once, by the rank that owns it in the yarn's submesh (a parent
        # dof's owner need not hold a cell of that yarn: ghosts are shared by facets, not vertices)
        masters = []
        for y in ms.yarns:
            glob = parent_global[y.to_parent[:y.V.dofmap.index_map.size_local]]
            keep = ~np.isin(glob, images[y.yarn][0])
            masters.append(np.sort(glob[keep]))
        counts = np.array([len(m) for m in masters])
        n_local = int(counts.sum())
        offset = comm.exscan(n_local) or 0
        self.n = comm.allreduce(n_local, op=MPI.SUM)
        self.multiplier = self.n
        self.n_local = n_local + (1 if comm.rank == comm.size - 1 else 0)
        self.start = offset
        # parent global dof -> unknown, per yarn, known on every rank (gathered once)
        self.lookup = []
        pos = offset
        mine = []
        for m in masters:
            mine.append((m, np.arange(pos, pos + len(m), dtype=np.int64)))
            pos += len(m)
        every = comm.allgather(mine)
        for i in range(len(ms.yarns)):
            keys = np.concatenate([part[i][0] for part in every])
            vals = np.concatenate([part[i][1] for part in every])
            order = np.argsort(keys)
            self.lookup.append((keys[order], vals[order]))

    def unknown(self, i: int, parent_global: np.ndarray) -> np.ndarray:
        """Unknown index of yarn i at parent global dofs (slaves resolved to their masters)."""
        img_keys, img_vals = self.images[i]
        master = np.asarray(parent_global, dtype=np.int64).copy()
        if len(img_keys):
            k = np.minimum(np.searchsorted(img_keys, master), len(img_keys) - 1)
            hit = img_keys[k] == master
            master[hit] = img_vals[k[hit]]
        keys, vals = self.lookup[i]
        k = np.minimum(np.searchsorted(keys, master), max(len(keys) - 1, 0))
        if len(master) and (len(keys) == 0 or np.any(keys[k] != master)):
            raise SolverError(f"yarn {i}: a dof has no master unknown (periodic images inconsistent)")
        return vals[k]

    def matrix(self, rows_local: int, rows_global: int, entries) -> PETSc.Mat:
        """A (rows x unknowns) AIJ matrix from (row global, column, value) triples of owned rows."""
        r, c, v = (np.asarray(a) for a in entries)
        A = PETSc.Mat().createAIJ(((rows_local, rows_global), (self.n_local, self.n + 1)), comm=self.comm)
        start = self.comm.exscan(rows_local) or 0
        local = r - start
        order = np.lexsort((c, local))
        local, c, v = local[order], c[order], v[order]
        indptr = np.concatenate(([0], np.cumsum(np.bincount(local, minlength=rows_local)))).astype(PETSc.IntType)
        A.setPreallocationCSR((indptr, c.astype(PETSc.IntType), v.astype(PETSc.ScalarType)))
        A.assemble()
        return A


class _Triplets:
    """The combined matrix on this rank's rows in CSR, from (row, column, value) triplets given on
    any rank (each routed to its row's owner; repeated entries summed). Constant triplets (plates,
    pin) come yarn by yarn (`add_fixed`, collective) and are compressed as they come; `freeze`
    then fixes the pattern with the contact triplets' (row, column), after which `csr(values)`
    moves only the contact values and adds them to the constant part. The indices are never held
    as one big uncompressed array (that was the solver's memory peak on large coupons)."""

    def __init__(self, comm: MPI.Comm, start: int, n_local: int):
        self.comm, self.start, self.n_local = comm, start, n_local
        self.starts = np.array(comm.allgather(start))
        self.n_cols = comm.allreduce(n_local, op=MPI.SUM)
        self._fixed = []  # compressed (local row, column, value) pieces

    def _coo(self, rows, cols, vals) -> scipy.sparse.csr_matrix:
        """A local-rows CSR of owned-row triplets, repeated entries summed, zeros kept."""
        return scipy.sparse.coo_matrix((vals, (rows - self.start, cols)), shape=(self.n_local, self.n_cols)).tocsr()

    def add_fixed(self, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray) -> None:
        plan = self._plan(rows)
        A = self._coo(*(self._route(plan, np.asarray(a, dt)) for a, dt in
                        ((rows, np.int64), (cols, np.int64), (vals, np.float64)))).tocoo()
        self._fixed.append((A.row, A.col, A.data))

    def freeze(self, rows: np.ndarray, cols: np.ndarray) -> None:
        """Fix the pattern: the constant entries and these (row, column) of the contact values."""
        self.plan = self._plan(rows)
        r, c = (self._route(self.plan, np.asarray(a, np.int64)) for a in (rows, cols))
        fr, fc, fv = (np.concatenate(a) for a in zip(*self._fixed)) if self._fixed else (np.zeros(0, int),) * 3
        self._fixed = None
        U = self._coo(np.concatenate([fr + self.start, r]), np.concatenate([fc, c]),
                      np.concatenate([fv, np.zeros(len(r))]))
        del fr, fc, fv
        self.base = U.data.copy()  # the constant part, in the pattern's order
        U.data = np.arange(U.nnz, dtype=np.float64)  # each entry's position, to look the contact's up
        small = np.int32 if U.nnz < 2**31 else np.int64
        self.positions = np.asarray(U[r - self.start, c]).ravel().astype(small) if len(r) else np.zeros(0, small)
        self.indptr, self.indices = U.indptr.astype(PETSc.IntType), U.indices.astype(PETSc.IntType)

    def _plan(self, rows: np.ndarray):
        owner = np.searchsorted(self.starts, rows, side="right") - 1
        order = np.argsort(owner, kind="stable").astype(np.int64)
        send = np.bincount(owner, minlength=self.comm.size).astype(np.int64)
        recv = np.array(self.comm.alltoall(send.tolist()), dtype=np.int64)
        return order, send, recv

    def _route(self, plan, data: np.ndarray) -> np.ndarray:
        order, send, recv = plan
        data = data[order]
        if self.comm.size == 1:
            return data
        out = np.empty(int(recv.sum()), dtype=data.dtype)
        sd = np.concatenate(([0], np.cumsum(send)[:-1]))
        rd = np.concatenate(([0], np.cumsum(recv)[:-1]))
        self.comm.Alltoallv([data, (send, sd)], [out, (recv, rd)])
        return out

    def csr(self, values: np.ndarray) -> np.ndarray:
        """Summed values (constant part + these contact values) in the order of (indptr, indices)."""
        v = self._route(self.plan, np.asarray(values, np.float64))
        out = np.bincount(self.positions, weights=v, minlength=len(self.indices)).astype(np.float64, copy=False)
        out += self.base  # in place: on a coupon each array of this size is 0.2 GB per rank
        return out.astype(PETSc.ScalarType, copy=False)


def _owned_rows(V: dolfinx.fem.FunctionSpace) -> tuple[np.ndarray, np.ndarray]:
    imap = V.dofmap.index_map
    local = np.arange(imap.size_local, dtype=np.int32)
    return local, imap.local_to_global(local)


# --- the problem --------------------------------------------------------------------------

class ContactProblem:
    """Assembled operators of one textile's plates; `solve` runs the contact iteration."""

    def __init__(self, ms: MidSurfaces, params: PlateParameters = PlateParameters(),
                 options: SolverOptions = SolverOptions(), loads: dict | None = None,
                 foundation_stiffness: float = 0.0, log=print):
        self.ms, self.params, self.options = ms, params, options
        self._penalty = options.augmented_penalty if options.method == "augmented" else params.Ec
        self.comm = ms.V.mesh.comm
        self.log = log if self.comm.rank == 0 else None
        self.times = {}
        t0 = time.perf_counter()
        self.layout = _Layout(ms)
        self._triplets = _Triplets(self.comm, self.layout.start, self.layout.n_local)
        V_imap = ms.V.dofmap.index_map
        self._parent_global = V_imap.local_to_global(
            np.arange(V_imap.size_local + V_imap.num_ghosts, dtype=np.int32))
        self._plates(loads or {}, foundation_stiffness)
        self._mean_constraint(foundation_stiffness)
        self._contact_setup()
        for vec in self.__dict__.pop("_parent_vecs", {}).values():
            vec.destroy()
        self.times["assemble"] = time.perf_counter() - t0

    def _parents(self, y, A: PETSc.Mat) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A matrix assembled on yarn y's space as (row, column, value) triplets of its owned rows,
        rows and columns as global parent dofs. Columns may be dofs this rank does not hold (rows
        assembled elsewhere arrive with their couplings): their parents come from their owners."""
        indptr, cols, vals = A.getValuesCSR()
        rows = self._parent_global[y.to_parent[np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))]]
        return rows, self._column_parents(y, cols), vals

    def _column_parents(self, y, cols: np.ndarray) -> np.ndarray:
        """Global parent dofs of yarn y's dofs given by their global index in y's space (any rank's)."""
        cache = self.__dict__.setdefault("_parent_vecs", {})  # per yarn: its owned dofs' parents
        if y.yarn not in cache:
            imap = y.V.dofmap.index_map
            cache[y.yarn] = PETSc.Vec().createMPI((imap.size_local, imap.size_global), comm=self.comm)
            cache[y.yarn].getArray()[:] = self._parent_global[y.to_parent[:imap.size_local]]
        owned = cache[y.yarn]
        wanted, back = np.unique(cols, return_inverse=True)
        got = PETSc.Vec().createSeq(len(wanted), comm=PETSc.COMM_SELF)
        index = PETSc.IS().createGeneral(wanted.astype(PETSc.IntType), comm=PETSc.COMM_SELF)
        scatter = PETSc.Scatter().create(owned, index, got, None)
        scatter.scatter(owned, got, addv=PETSc.InsertMode.INSERT_VALUES, mode=PETSc.ScatterMode.FORWARD)
        parents = np.rint(got.getArray()).astype(np.int64)[back]
        for obj in (got, index, scatter):
            obj.destroy()
        return parents

    def _yarn_map(self, y) -> PETSc.Mat:
        rows_local, rows_global = _owned_rows(y.V)
        cols = self.layout.unknown(y.yarn, self._parent_global[y.to_parent[rows_local]])
        return self.layout.matrix(len(rows_local), y.V.dofmap.index_map.size_global,
                                  (rows_global, cols, np.ones(len(cols))))

    def _plates(self, loads, kf):
        p = self.params
        self.R, self.b_plate = [], None
        b = PETSc.Vec().createMPI((self.layout.n_local, self.layout.n + 1), comm=self.comm)
        b.set(0.0)
        for y in self.ms.yarns:
            msh = y.mesh
            facets = _seam_facet_tags(y)
            dS = ufl.Measure("dS", msh, subdomain_data=facets, subdomain_id=1)
            c = dolfinx.fem.Constant
            Db1, Db2, Db12 = (c(msh, float(v)) for v in (p.Db1, p.Db2, p.Db12))
            u, v = ufl.TrialFunction(y.V), ufl.TestFunction(y.V)
            a = c0ip_bending(u, v, y.d, Db1, Db2, Db12, c(msh, p.alpha), y.dx, dS) \
                + tension(u, v, y.d, c(msh, float(p.sigma1)), y.dx)
            # energies act on z0 + w: the right-hand side is -a(z0, v) (the restoring force)
            L = -ufl.action(a, y.z0)
            if kf:
                a = a + foundation(u, v, c(msh, float(kf)), y.dx)
            if y.yarn in loads:  # a number [N/mm^2] or a function of the SpatialCoordinate
                q = loads[y.yarn]
                q = q(ufl.SpatialCoordinate(msh)) if callable(q) else c(msh, float(q))
                L = L + load(v, q, y.dx)
            A = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(a))
            A.assemble()
            bi = dolfinx.fem.petsc.assemble_vector(dolfinx.fem.form(L))
            bi.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            R = self._yarn_map(y)
            rows, cols, vals = self._parents(y, A)
            self._triplets.add_fixed(self.layout.unknown(y.yarn, rows), self.layout.unknown(y.yarn, cols), vals)
            R.multTransposeAdd(bi, b, b)
            self.R.append(R)
            A.destroy()
            bi.destroy()
        self.b_plate = b

    def _mean_constraint(self, kf: float):
        """The common vertical translation (the energy's null space when there is no foundation).

        Equivalent to a multiplier on the area-weighted mean of all w, but sparse: the net load is
        spread over the area as that multiplier's reaction would be (b -= (sum b / area) m), one
        unknown is pinned through the multiplier's row, and the solution is shifted to zero mean
        afterwards. (A dense multiplier row made MUMPS' analysis take over a minute at 3e5 dofs.)
        With a foundation the system is regular and the multiplier row is the identity."""
        m = PETSc.Vec().createMPI((self.layout.n_local, self.layout.n + 1), comm=self.comm)
        m.set(0.0)
        for y, R in zip(self.ms.yarns, self.R):
            v = ufl.TestFunction(y.V)
            mi = dolfinx.fem.petsc.assemble_vector(dolfinx.fem.form(v * y.dx))
            mi.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            R.multTransposeAdd(mi, m, m)
            mi.destroy()
        self.area_weights, self.area = m, m.sum()
        self.free_translation = not kf
        mult = self.layout.multiplier
        if self.free_translation:
            self.b_plate.axpy(-self.b_plate.sum() / self.area, m)
            entries = [(0, mult), (mult, 0)]  # pin unknown 0
        else:
            entries = [(mult, mult)]
        if self.comm.rank != 0:  # COO entries are summed over ranks: give them once
            entries = []
        self._triplets.add_fixed(np.array([e[0] for e in entries], np.int64),
                                 np.array([e[1] for e in entries], np.int64), np.ones(len(entries)))

    def _contact_setup(self):
        """Per adjacent pair: its overlap, the contact forms on the upper yarn, and where its
        entries go in K. The pair's gap and pressure live in arrays over its overlap dofs only;
        the forms read them from the upper yarn's scratch Functions, filled just before use (per
        yarn, not per pair: whole-yarn Functions and matrices per pair cost memory in proportion to
        pairs x yarn size, gigabytes on large coupons)."""
        p = self.params
        yarns = self.ms.yarns
        self.pairs = []
        self._scratch = {}  # upper yarn -> (g, lam, g0, -g at quadrature points): what the forms read
        coo_rows, coo_cols = [], []  # T^T M T's pattern, as unknowns
        cell_order = {}
        quadrature = basix.make_quadrature(basix.CellType.triangle, 4)[0]
        for (u, l), cells in self.ms.contact.items():
            yu, yl = yarns[u], yarns[l]
            if u not in self._scratch:
                g_fn, lam_fn, g0_fn = (dolfinx.fem.Function(yu.V, name=n) for n in ("gap", "pressure", "gap0"))
                # -g at the contact forms' quadrature points (degree 4); compiled on every rank (collective)
                # g - lam / Ec there: its sign is the contact state the forms integrate with
                shifted = g_fn - lam_fn / dolfinx.fem.Constant(yu.mesh, float(self._penalty))
                self._scratch[u] = (g_fn, lam_fn, g0_fn, dolfinx.fem.Expression(-g_fn, quadrature),
                                    dolfinx.fem.Expression(shifted, quadrature))
                cell_order[u] = np.argsort(yu.parent_cells)
            g_fn, lam_fn, g0_fn, *_ = self._scratch[u]
            # the pair's cells on u's submesh
            k = np.searchsorted(yu.parent_cells, cells, sorter=cell_order[u])
            sub_cells = np.sort(cell_order[u][k]).astype(np.int32)
            tags = dolfinx.mesh.meshtags(yu.mesh, 2, sub_cells, np.full(len(sub_cells), 1, np.int32))
            dx = ufl.Measure("dx", yu.mesh, subdomain_data=tags, subdomain_id=1)
            Ec, Et = (dolfinx.fem.Constant(yu.mesh, float(v)) for v in (self._penalty, p.Et))
            v = ufl.TestFunction(yu.V)
            a = dolfinx.fem.form(contact_mass(ufl.TrialFunction(yu.V), v, g_fn, Ec, Et, dx, shift=lam_fn / Ec))
            # the right-hand side T^T (f - M g0): the pressure's load where contact is active, and
            # the stiffness acting on the initial gap
            L = dolfinx.fem.form(contact_pressure(v, g_fn, Ec, Et, lam_fn, dx)
                                 - contact_mass(g0_fn, v, g_fn, Ec, Et, dx, shift=lam_fn / Ec))
            pen_form = dolfinx.fem.form(ufl.max_value(-g_fn, 0) * dx(metadata={"quadrature_degree": 4}))
            energy = dolfinx.fem.form(contact_energy(g_fn, Ec, Et, lam_fn, dx))
            # the overlap's dofs (owned and ghost) on u and on l (the same points)
            dofs = self.ms.contact_dofs[(u, l)]
            du, dl = dofs[:, 0], dofs[:, 1]
            n_owned = yu.V.dofmap.index_map.size_local
            g0 = (yu.z0.x.array[du] - yu.t.x.array[du] / 2) - (yl.z0.x.array[dl] + yl.t.x.array[dl] / 2)
            parent = self._parent_global[yu.to_parent[du]]  # crossing yarns share the parent's dofs
            cu, cl = self.layout.unknown(u, parent), self.layout.unknown(l, parent)
            # M = k(g) u v on the overlap: its owned rows' entries (i, j) as parent dofs (a column
            # may be a dof this rank does not hold: rows get couplings from cells elsewhere)
            M = dolfinx.fem.create_matrix(a)
            nnz = int(M.indptr[n_owned])
            i = self._parent_global[yu.to_parent[np.repeat(np.arange(n_owned), np.diff(M.indptr[:n_owned + 1]))]]
            j = self._column_parents(yu, M.index_map(1).local_to_global(M.indices[:nnz]))
            # T^T M T: entry (i, j) adds +m at (u_i, u_j) and (l_i, l_j), -m at (u_i, l_j) and (l_i, u_j)
            ui, uj, li, lj = (self.layout.unknown(y, d) for y, d in ((u, i), (u, j), (l, i), (l, j)))
            coo_rows.append(np.concatenate([ui, ui, li, li]))
            coo_cols.append(np.concatenate([uj, lj, uj, lj]))
            del i, j, ui, uj, li, lj
            owned = np.flatnonzero(du < n_owned)
            self.pairs.append(dict(pair=(u, l), dofs=du, owned=owned, g0=g0, g=g0.copy(), lam=np.zeros(len(du)),
                                   cu=cu, cl=cl, nnz=nnz, a=a, L=L, pen_form=pen_form, energy=energy, M=M,
                                   cells=sub_cells[sub_cells < yu.mesh.topology.index_map(2).size_local]))
        self._triplets.freeze(np.concatenate(coo_rows) if coo_rows else np.zeros(0, np.int64),
                              np.concatenate(coo_cols) if coo_cols else np.zeros(0, np.int64))
        # x at every unknown an overlap dof of this rank needs, gathered by one scatter
        need = np.unique(np.concatenate([np.concatenate([pr["cu"], pr["cl"]]) for pr in self.pairs]
                                        + [np.zeros(0, np.int64)]))
        for pr in self.pairs:
            pr["gu"], pr["gl"] = np.searchsorted(need, pr.pop("cu")), np.searchsorted(need, pr.pop("cl"))
            pr["bu"], pr["bl"] = need[pr["gu"][pr["owned"]]], need[pr["gl"][pr["owned"]]]
        self._x_needed = PETSc.Vec().createSeq(len(need), comm=PETSc.COMM_SELF)
        index = PETSc.IS().createGeneral(need.astype(PETSc.IntType), comm=PETSc.COMM_SELF)
        self._x_gather = PETSc.Scatter().create(self.b_plate, index, self._x_needed, None)
        index.destroy()

    def _fill(self, pr) -> None:
        """Put the pair's gap and pressure into its upper yarn's scratch Functions."""
        g_fn, lam_fn, g0_fn, *_ = self._scratch[pr["pair"][0]]
        g_fn.x.array[pr["dofs"]] = pr["g"]
        lam_fn.x.array[pr["dofs"]] = pr["lam"]
        g0_fn.x.array[pr["dofs"]] = pr["g0"]

    # --- iteration ------------------------------------------------------------------------

    def _energy(self, x: PETSc.Vec) -> float:
        """The energy at x (plates, pin and contact, with the current pressures); the gaps are
        updated to x. The active-set steps are Newton steps on it: it decides their damping."""
        self._update_gaps(x)
        y = x.duplicate()
        self._A_fixed.mult(x, y)
        plates = 0.5 * x.dot(y) - self.b_plate.dot(x)
        y.destroy()
        contact = 0.0
        for pr in self.pairs:
            self._fill(pr)
            contact += dolfinx.fem.assemble_scalar(pr["energy"])
        return plates + self.comm.allreduce(contact, op=MPI.SUM)

    def _update_gaps(self, x: PETSc.Vec):
        """g = g0 + w_u - w_l at every overlap dof of this rank (ghosts included)."""
        self._x_gather.scatter(x, self._x_needed, addv=PETSc.InsertMode.INSERT_VALUES,
                               mode=PETSc.ScatterMode.FORWARD)
        xs = self._x_needed.getArray(readonly=True)
        for pr in self.pairs:
            pr["g"] = pr["g0"] + xs[pr["gu"]] - xs[pr["gl"]]

    def _state(self) -> np.ndarray:
        """The contact state where the forms integrate: g < lam / Ec at each quadrature point of
        the pairs' owned cells (the matrix depends on these alone, so when none changes the
        iteration has reached its fixed point)."""
        parts = []
        for pr in self.pairs:
            if len(pr["cells"]):
                self._fill(pr)
                u = pr["pair"][0]
                parts.append(self._scratch[u][4].eval(self.ms.yarns[u].mesh, pr["cells"]).ravel() < 0)
        return np.concatenate(parts) if parts else np.zeros(0, bool)

    def max_penetration(self) -> float:
        """Largest -g over the overlap dofs [mm] (0 when no dof penetrates)."""
        local = max((float(np.max(-pr["g"][pr["owned"]])) for pr in self.pairs if len(pr["owned"])), default=0.0)
        return self.comm.allreduce(local, op=MPI.MAX)

    def penetration(self) -> tuple[float, float]:
        """What the contact energy sees: the largest -g at the quadrature points of the contact
        forms [mm], and the penetration volume, the integral of max(0, -g) over the overlaps [mm^3]."""
        worst, volume = 0.0, 0.0
        for pr in self.pairs:
            self._fill(pr)
            u = pr["pair"][0]
            if len(pr["cells"]):
                vals = self._scratch[u][3].eval(self.ms.yarns[u].mesh, pr["cells"])
                worst = max(worst, float(np.max(vals)))
            volume += dolfinx.fem.assemble_scalar(pr["pen_form"])
        return self.comm.allreduce(worst, op=MPI.MAX), self.comm.allreduce(volume, op=MPI.SUM)

    def _assemble(self) -> tuple[PETSc.Mat, PETSc.Vec]:
        """The combined matrix (values only: its pattern is fixed) and right-hand side."""
        values = []
        b = self.b_plate.copy()
        rows, adds = [], []
        for pr in self.pairs:
            self._fill(pr)
            M = pr["M"]
            M.set_value(0.0)
            dolfinx.fem.assemble_matrix(M, pr["a"])
            M.scatter_reverse()
            m = M.data[:pr["nnz"]]
            values.append(np.concatenate([m, -m, -m, m]))
            f = dolfinx.fem.assemble_vector(pr["L"])
            f.scatter_reverse(dolfinx.la.InsertMode.add)
            v = f.array[pr["dofs"][pr["owned"]]]
            rows += [pr["bu"], pr["bl"]]
            adds += [v, -v]
        if rows:
            b.setValues(np.concatenate(rows).astype(PETSc.IntType), np.concatenate(adds),
                        addv=PETSc.InsertMode.ADD_VALUES)
        b.assemble()
        t = self._triplets
        contact = np.concatenate(values) if values else np.zeros(0)
        self.K.setValuesCSR(t.indptr, t.indices, t.csr(contact), addv=PETSc.InsertMode.INSERT_VALUES)
        self.K.assemble()
        return self.K, b

    def _first_matrix(self):
        """The combined matrix, created from the fixed pattern of plates, pin and contact pairs."""
        if getattr(self, "K", None) is not None:
            return
        t = self._triplets
        K = PETSc.Mat().createAIJ(((self.layout.n_local, self.layout.n + 1),) * 2, comm=self.comm)
        K.setPreallocationCSR((t.indptr, t.indices, np.zeros(len(t.indices), PETSc.ScalarType)))
        K.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        self.K = K
        A = K.duplicate()  # the constant part alone (plates and pin), for the energy
        A.setValuesCSR(t.indptr, t.indices, t.base.astype(PETSc.ScalarType), addv=PETSc.InsertMode.INSERT_VALUES)
        A.assemble()
        self._A_fixed = A

    def solve(self) -> Solution:
        opts, comm = self.options, self.comm
        t_start = time.perf_counter()
        self._first_matrix()
        ksp = PETSc.KSP().create(comm)
        prefix = f"tfx_{id(self)}_"
        ksp.setOptionsPrefix(prefix)
        petsc_opts = PETSc.Options()
        for k, v in opts.petsc.items():
            petsc_opts[prefix + k] = v
        ksp.setFromOptions()
        x = self.K.createVecRight()
        x.set(0.0)
        x_old, step = x.duplicate(), x.duplicate()
        energy = self._energy(x)  # updates the gaps
        history, seen = [], {}
        state = self._state()
        converged, it, updates, reason = False, 0, 0, ""
        t_factor = 0.0
        while True:
            for inner in range(opts.max_iterations):
                it += 1
                t0 = time.perf_counter()
                K, b = self._assemble()
                r = K.createVecLeft()
                K.mult(x, r)
                r.axpy(-1.0, b)
                res = r.norm() / max(b.norm(), 1e-300)
                r.destroy()
                ksp.setOperators(K)
                t1 = time.perf_counter()
                x.copy(x_old)
                ksp.solve(b, x)
                t_factor += time.perf_counter() - t1
                ksp_reason = ksp.getConvergedReason()
                b.destroy()
                if ksp_reason <= 0 or _null_pivots(ksp) > 0:
                    hint = ("with Et = 0 a yarn that touches no other yarn is held by nothing: give Et > 0"
                            if self.params.Et == 0 else "check the stiffnesses (Db1, Db2, sigma1) for zeros")
                    raise SolverError(f"the linear system is singular at contact iteration {it} (PETSc reason "
                                      f"{ksp_reason}, {_null_pivots(ksp)} null pivots): {hint}; iteration log: "
                                      f"{history}")
                if not np.isfinite(x.norm()):
                    raise SolverError(f"the solution is not finite (NaN or Inf) at contact iteration {it}; "
                                      f"iteration log: {history}")
                # damping: the step is the Newton step of the (convex) energy at the current
                # contact states; where it raises the energy, halve it (undamped, the active set
                # can cycle between states)
                alpha, trial = 1.0, self._energy(x)
                if trial > energy + 1e-10 * (abs(energy) + abs(trial)):
                    x.copy(step)
                    step.axpy(-1.0, x_old)
                    while trial > energy + 1e-10 * (abs(energy) + abs(trial)):
                        alpha /= 2
                        if alpha < 1e-12:
                            raise SolverError(f"the damped contact step found no lower energy at iteration {it} "
                                              f"(energy {energy:.6e}); iteration log: {history}")
                        x_old.copy(x)
                        x.axpy(alpha, step)
                        trial = self._energy(x)
                energy = trial  # the gaps are at x
                new = self._state()
                changed = comm.allreduce(int(np.sum(new != state)), op=MPI.SUM)
                active = comm.allreduce(int(np.sum(new)), op=MPI.SUM)
                pen = self.max_penetration()
                line = dict(iteration=it, active=active, changed=changed, max_penetration=pen,
                            residual=res, step=alpha, energy=energy, time_s=time.perf_counter() - t0)
                history.append(line)
                if self.log:
                    self.log(f"contact it {it:3d}: active {active:6d}, changed {changed:5d}, "
                             f"max penetration {pen:.3e} mm, residual {res:.2e}"
                             + (f", step {alpha:.3g}" if alpha < 1 else "") + f", {line['time_s']:.2f} s")
                key = hashlib.sha1(np.packbits(new).tobytes()).hexdigest()
                digest = hashlib.sha1("".join(comm.allgather(key)).encode()).hexdigest()  # the global state
                state = new
                if changed == 0 and inner > 0 and alpha == 1.0:
                    converged, reason = True, "converged: no contact state changed"
                    break
                # a state seen before is a cycle only if the energy has not fallen since (the
                # damped steps lower it every time they move)
                if digest in seen and seen[digest][0] < it - 1 and changed > 0 \
                        and energy >= seen[digest][1] - 1e-10 * abs(energy):
                    reason = f"the contact states cycle: iteration {it} repeats iteration {seen[digest][0]}"
                    # augmented: the inner active set need not settle exactly (its flips are dofs
                    # at zero gap); the Uzawa updates go on and the penetration decides
                    converged = opts.method == "augmented"
                    if self.log:
                        self.log(f"contact: {reason} ({changed} states), "
                                 + ("updating the pressure" if converged else "stopping"))
                    break
                seen[digest] = (it, energy)
            else:
                converged = False
                reason = (f"the contact iteration reached its cap of {opts.max_iterations} steps with "
                          f"{changed} contact states still changing")
            if opts.method == "penalty" or not converged:
                break
            pen = self.max_penetration()
            if pen <= opts.penetration_tol or updates >= opts.max_updates:
                converged = pen <= opts.penetration_tol
                reason = (f"converged: penetration {pen:.2e} mm <= {opts.penetration_tol:g} mm" if converged else
                          f"{updates} augmented-Lagrangian updates (the cap) left a penetration of {pen:.2e} mm "
                          f"> {opts.penetration_tol:g} mm")
                break
            updates += 1
            for pr in self.pairs:  # Uzawa: lam <- max(0, lam - Ec g)
                pr["lam"] = np.maximum(0.0, pr["lam"] - self._penalty * pr["g"])
            state, seen = self._state(), {}  # new multipliers: earlier states say nothing about cycling
            energy = self._energy(x)  # and a new energy
            if self.log:
                self.log(f"augmented Lagrangian update {updates}: max penetration {pen:.3e} mm")
        ksp.destroy()  # with the factors
        for obj in (self.K, self._A_fixed, x_old, step):  # K and A are rebuilt if solve() is called again
            obj.destroy()
        self.K = self._A_fixed = None
        release_freed_memory()  # MUMPS' factors back to the system before the outputs are made
        if self.free_translation:  # zero area-weighted mean (the gaps do not change)
            ones = x.duplicate()
            ones.set(1.0)
            ones.setValue(self.layout.multiplier, 0.0)
            ones.assemble()
            x.axpy(-self.area_weights.dot(x) / self.area, ones)
            ones.destroy()
        w = []
        for y, R in zip(self.ms.yarns, self.R):
            f = dolfinx.fem.Function(y.V, name="w")
            R.mult(x, f.x.petsc_vec)
            f.x.scatter_forward()
            w.append(f)
        self.times.update(solve=time.perf_counter() - t_start, factor=t_factor)
        self.x = x
        worst, volume = self.penetration()
        return Solution(w=w, iterations=it, updates=updates, history=history,
                        max_penetration=self.max_penetration(), converged=converged, times=dict(self.times),
                        reason=reason,
                        penetration_quadrature=worst, penetration_volume=volume)


def _null_pivots(ksp: PETSc.KSP) -> int:
    """Null pivots MUMPS found (with ICNTL(24) = 1, as DIRECT_LDLT asks); 0 for other solvers."""
    try:
        return int(ksp.getPC().getFactorMatrix().getMumpsInfog(28))
    except (PETSc.Error, AttributeError):
        return 0


def gap_fields(problem: ContactProblem) -> list:
    """Per yarn, its gap to the yarn below it [mm] (NaN-free: 0 where nothing is below) and the
    contact state (1 where the gap is closed), as Functions on its mid-surface, for output."""
    out = []
    for y in problem.ms.yarns:
        gap = dolfinx.fem.Function(y.V, name="gap_below")
        state = dolfinx.fem.Function(y.V, name="contact")
        for pr in problem.pairs:
            if pr["pair"][0] == y.yarn:
                gap.x.array[pr["dofs"]] = pr["g"]
                state.x.array[pr["dofs"]] = (pr["g"] < 0).astype(float)
        out.append((gap, state))
    return out


def _seam_facet_tags(y) -> dolfinx.mesh.MeshTags:
    """Interior facets of a yarn's submesh that touch a cell of the unit cell (tag 1): the interior
    facets of its footprint and the periodic seam facets between the cell and the ghost strip."""
    msh = y.mesh
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, tdim)
    f2c = msh.topology.connectivity(tdim - 1, tdim)
    n_facets = msh.topology.index_map(tdim - 1).size_local + msh.topology.index_map(tdim - 1).num_ghosts
    kind = np.zeros(msh.topology.index_map(tdim).size_local + msh.topology.index_map(tdim).num_ghosts, np.int32)
    kind[y.cell_kind.indices] = y.cell_kind.values
    offsets, links = f2c.offsets[: n_facets + 1], f2c.array
    two = np.flatnonzero(np.diff(offsets) == 2)
    first, second = links[offsets[two]], links[offsets[two] + 1]
    marked = two[(kind[first] == REAL) | (kind[second] == REAL)].astype(np.int32)
    return dolfinx.mesh.meshtags(msh, tdim - 1, marked, np.ones(len(marked), np.int32))


def solve(ms: MidSurfaces, params: PlateParameters = PlateParameters(),
          options: SolverOptions = SolverOptions(), log=print, **kwargs) -> Solution:
    """Solve the textile's plates with contact; see ContactProblem."""
    return ContactProblem(ms, params, options, log=log, **kwargs).solve()
