"""Contact pairs as data: for each vertically adjacent pair (upper u, lower l), its overlap dofs,
initial gap, where its unknowns sit in the gathered vector, and the contact forms on u's overlap.

A pair's arrays live on its overlap only (whole-yarn objects per pair cost gigabytes on coupons
with a thousand pairs); the forms read the gap from one scratch Function per upper yarn, filled
just before use. The gap at a dof is g = g0 + x[u] - x[l] (T x: crossing yarns share the parent
mesh's nodes, so the lower yarn's value at the same point is its own dof there).
A mould (parameters.Mould) adds one constraint per yarn node and platen, with the platen in the
place of the other yarn: g = z - t/2 - bottom >= 0 and g = top - (z + t/2) >= 0.
Where the yarns flatten (solver/flattening.py), a yarn's bottom and top surfaces have unknowns of
their own: a gap reads the upper yarn's bottom and the lower yarn's top, a platen the yarn's bottom
or top, and the maximum packing adds a constraint between a node's two (PACKING).
"""

from dataclasses import dataclass, replace

import numpy as np
import ufl
from petsc4py import PETSc

import dolfinx
from textile_fenicsx.plate.forms import contact_forms, penetration_volume
from textile_fenicsx.plate.mesh.midsurface import MidSurfaces
from textile_fenicsx.plate.solver.numbering import BOTTOM, TOP, Periodicity
from textile_fenicsx.plate.solver.parameters import Mould, PlateParameters

__all__ = ["ContactPair", "MouldRows", "Nodes", "PairForms", "build_pairs", "contact_nodes", "gathered_unknowns",
           "initial_gap", "jacobian_values", "mould_rows", "renewed_nodes", "residual_values"]

# a node's "other yarn" where it is a platen: no pair, no unknown
NONE = -1
# the pair of a maximum packing constraint (a yarn node's top against its own bottom)
PACKING = -2


@dataclass(frozen=True)
class PairForms:
    """Compiled forms of one pair on its upper yarn (the gap is the upper yarn's scratch `g`)."""

    g: dolfinx.fem.Function        # scratch gap Function of the upper yarn
    energy: dolfinx.fem.Form
    residual: dolfinx.fem.Form
    jacobian: dolfinx.fem.Form
    penetration: dolfinx.fem.Form
    matrix: dolfinx.la.MatrixCSR   # the Jacobian's storage (its owned rows' entries come first)
    nnz: int                       # entries of the owned rows
    kept: np.ndarray | None = None  # lumped: which of them are kept (the diagonal; the rest are 0)


@dataclass(frozen=True)
class ContactPair:
    """One pair's overlap. Arrays over the overlap dofs (owned and ghost) unless said otherwise."""

    upper: int
    lower: int
    dofs: np.ndarray      # the upper yarn's local dofs
    parent: np.ndarray    # their global parent dofs
    owner: np.ndarray     # the rank owning each parent dof (it may hold no cell of this pair)
    g0: np.ndarray        # initial gap [mm]
    margin: np.ndarray    # the gap the node keeps (midsurface margins: P2 overstatement, dips between nodes) [mm]
    at_u: np.ndarray      # positions of the unknowns of u and l in the gathered vector
    at_l: np.ndarray
    cells: np.ndarray     # the upper yarn's owned cells of the overlap
    forms: PairForms

    def gap(self, gathered: np.ndarray) -> np.ndarray:
        """g = g0 + w_u - w_l at the dofs, from the gathered unknowns [mm]."""
        return self.g0 + gathered[self.at_u] - gathered[self.at_l]

    def fill(self, g: np.ndarray) -> None:
        """Put this pair's gap into its upper yarn's scratch Function, for the forms."""
        self.forms.g.x.array[self.dofs] = g


def build_pairs(ms: MidSurfaces, numbering: Periodicity, params: PlateParameters, exact: bool,
                extra: np.ndarray | None = None, min_gap: float = 0.0, lumped: bool = False):
    """The pairs, and the (row, column) unknowns of T^T J T's entries in the order `jacobian_values`
    gives them, and the unknowns every pair (and `extra`: the mould's) needs (sorted: the gathered
    vector's layout). min_gap [mm] is added to every node's margin (initial_gap). lumped: the exact
    method's spring by the nodes' rule (forms/contact.py), its entries off the diagonal left out."""
    extra = np.zeros(0, np.int64) if extra is None else extra
    yarns = ms.yarns
    scratch, cell_order = {}, {}
    pending, rows, cols = [], [], []
    for (u, l), cells in ms.contact.items():
        yu = yarns[u]
        if u not in scratch:
            scratch[u] = dolfinx.fem.Function(yu.V, name="gap")
            cell_order[u] = np.argsort(yu.parent_cells)
        g = scratch[u]
        k = np.searchsorted(yu.parent_cells, cells, sorter=cell_order[u])
        sub_cells = np.sort(cell_order[u][k]).astype(np.int32)
        tags = dolfinx.mesh.meshtags(yu.mesh, 2, sub_cells, np.full(len(sub_cells), 1, np.int32))
        dx = ufl.Measure("dx", yu.mesh, subdomain_data=tags, subdomain_id=1)
        Ec, Et = (dolfinx.fem.Constant(yu.mesh, float(v)) for v in (params.Ec, params.Et))
        energy, residual, jacobian = (dolfinx.fem.form(f) for f in contact_forms(g, Ec, Et, dx, exact, lumped))
        M = dolfinx.fem.create_matrix(jacobian)
        n_owned = yu.V.dofmap.index_map.size_local
        nnz = int(M.indptr[n_owned])
        owned_rows = np.repeat(np.arange(n_owned), np.diff(M.indptr[:n_owned + 1]))
        kept = np.flatnonzero(M.indices[:nnz] == owned_rows) if lumped else None
        forms = PairForms(g, energy, residual, jacobian, dolfinx.fem.form(penetration_volume(g, dx)), M, nnz, kept)
        # the overlap's dofs on u and on l (the same points)
        du = ms.contact_dofs[(u, l)][:, 0]
        g0, margin = initial_gap(ms, u, l, min_gap)
        parent = numbering.parent_global[yu.to_parent[du]]  # crossing yarns share the parent's dofs
        owner = numbering.parent_owner(yu.to_parent[du])
        cu, cl = numbering.unknown(u, parent, BOTTOM), numbering.unknown(l, parent, TOP)
        # T^T J T: J's entry (i, j) adds +m at (u_i, u_j) and (l_i, l_j), -m at (u_i, l_j) and (l_i, u_j);
        # a column may be a dof this rank does not hold (rows get couplings from cells elsewhere)
        entries = slice(None) if kept is None else kept
        i = numbering.parent_global[yu.to_parent[owned_rows[entries]]]
        j = numbering.column_parents(yu, M.index_map(1).local_to_global(M.indices[:nnz][entries]))
        ui, uj, li, lj = (numbering.unknown(y, d, side) for y, d, side in
                          ((u, i, BOTTOM), (u, j, BOTTOM), (l, i, TOP), (l, j, TOP)))
        rows.append(np.concatenate([ui, ui, li, li]))
        cols.append(np.concatenate([uj, lj, uj, lj]))
        owned_cells = sub_cells[sub_cells < yu.mesh.topology.index_map(2).size_local]
        pending.append((u, l, du, parent, owner, g0, margin, cu, cl, owned_cells, forms))
    need = np.unique(np.concatenate([np.concatenate([p[7], p[8]]) for p in pending] + [extra.astype(np.int64)]))
    pairs = [ContactPair(u, l, du, parent, owner, g0, margin, np.searchsorted(need, cu), np.searchsorted(need, cl),
                         cells, forms) for u, l, du, parent, owner, g0, margin, cu, cl, cells, forms in pending]

    def cat(a):
        return np.concatenate(a) if a else np.zeros(0, np.int64)

    return pairs, (cat(rows), cat(cols)), need


def initial_gap(ms: MidSurfaces, u: int, l: int, min_gap: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The pair's gap before any displacement, bottom of u less top of l, and the margins its
    nodes keep, at its overlap dofs [mm] (from the mid-surfaces' z0, t and contact margins, plus
    the least gap `min_gap` asked for: SolverOptions.min_gap)."""
    yu, yl = ms.yarns[u], ms.yarns[l]
    du, dl = ms.contact_dofs[(u, l)][:, 0], ms.contact_dofs[(u, l)][:, 1]
    g0 = (yu.z0.x.array[du] - yu.t.x.array[du] / 2) - (yl.z0.x.array[dl] + yl.t.x.array[dl] / 2)
    return g0, ms.contact_margin.get((u, l), np.zeros(len(du))) + min_gap


def jacobian_values(pair: ContactPair, g: np.ndarray) -> np.ndarray:
    """The pair's T^T J T entries at gap g (in build_pairs' order): J assembled on its owned rows,
    each entry given to four places."""
    pair.fill(g)
    M = pair.forms.matrix
    M.set_value(0.0)
    dolfinx.fem.assemble_matrix(M, pair.forms.jacobian)
    M.scatter_reverse()
    m = M.data[:pair.forms.nnz]
    if pair.forms.kept is not None:
        m = m[pair.forms.kept]
    return np.concatenate([m, -m, -m, m])


def residual_values(pair: ContactPair, g: np.ndarray) -> np.ndarray:
    """This rank's part of the contact residual dE/dg at gap g, at the pair's dofs (+r to u's
    unknowns, -r to l's): the integrals over its owned cells, not yet summed over the ranks (the
    owner of a dof may hold no cell of the pair, and so no place for the sum)."""
    pair.fill(g)
    return dolfinx.fem.assemble_vector(pair.forms.residual).array[pair.dofs]


def gathered_unknowns(template: PETSc.Vec, need: np.ndarray) -> tuple[PETSc.Scatter, PETSc.Vec]:
    """A scatter that brings the unknowns `need` (global indices) of vectors like `template` to
    this rank, and its target."""
    target = PETSc.Vec().createSeq(len(need), comm=PETSc.COMM_SELF)
    index = PETSc.IS().createGeneral(need.astype(PETSc.IntType), comm=PETSc.COMM_SELF)
    scatter = PETSc.Scatter().create(template, index, target, None)
    index.destroy()
    return scatter, target


@dataclass(frozen=True)
class MouldRows:
    """The mould's constraints on this rank: one per owned yarn node (images left out, like the
    pairs') and platen. unknown: the yarn's unknown (global index); sign: +1 for the bottom platen
    (g = g0 + x), -1 for the top one (g = g0 - x); g0: the gap at x = 0 [mm]."""

    unknown: np.ndarray
    sign: np.ndarray
    g0: np.ndarray


def mould_rows(ms: MidSurfaces, numbering: Periodicity, images: list[np.ndarray], mould: Mould,
               min_gap: float = 0.0) -> MouldRows:
    """Every yarn node between the platens: z - t/2 >= bottom + min_gap and z + t/2 <= top - min_gap
    at its owned, non-image dofs (each unknown once over the ranks)."""
    parts = []
    for y, image in zip(ms.yarns, images):
        dofs = np.flatnonzero(~image[:y.V.dofmap.index_map.size_local])
        u, top = numbering.yarn_unknowns(y, dofs, BOTTOM), numbering.yarn_unknowns(y, dofs, TOP)
        z0, t = y.z0.x.array[dofs], y.t.x.array[dofs]
        ones = np.ones(len(u))
        parts.append((np.concatenate([u, top]), np.concatenate([ones, -ones]),
                      np.concatenate([z0 - t / 2 - mould.bottom, mould.top - (z0 + t / 2)]) - min_gap))
    unknown, sign, g0 = (np.concatenate(a) for a in zip(*parts))
    return MouldRows(unknown.astype(np.int64), sign, g0)


@dataclass(frozen=True)
class Nodes:
    """The exact method's constraints g >= 0: one per owned overlap node of each pair (a node and
    its periodic image give one), then the mould's. Arrays over the constraints of this rank;
    a platen takes the place of one of the node's two yarns: there, at_* is the gathered vector's
    extra slot (a 0) and rows_* is NONE."""

    pair: np.ndarray      # index of the node's pair (NONE: the mould)
    at: np.ndarray        # position of the node in its pair's dofs
    at_u: np.ndarray      # positions of the unknowns of u and l in the gathered vector
    at_l: np.ndarray
    rows_u: np.ndarray    # the unknowns of u and l (global indices)
    rows_l: np.ndarray
    g0: np.ndarray        # initial gap less the node's margin [mm]: the constraint is g0 + C x >= 0

    def gap(self, gathered: np.ndarray) -> np.ndarray:
        """g at the nodes from the gathered unknowns (with the extra 0 slot at their end) [mm]."""
        return self.g0 + gathered[self.at_u] - gathered[self.at_l]

    def _entries(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """C^T C's (row, column, sign) before the platens' places are left out."""
        u, l = self.rows_u, self.rows_l
        one = np.ones(len(u))
        return np.concatenate([u, u, l, l]), np.concatenate([u, l, u, l]), np.concatenate([one, -one, -one, one])

    def pattern(self) -> tuple[np.ndarray, np.ndarray]:
        """(rows, columns) of C^T C's entries, in the order of `values`."""
        rows, cols, _ = self._entries()
        keep = (rows != NONE) & (cols != NONE)
        return rows[keep], cols[keep]

    def values(self, c: np.ndarray) -> np.ndarray:
        """C^T diag(c) C's entries for the nodal stiffnesses c (0 where a node is inactive)."""
        rows, cols, sign = self._entries()
        return (sign * np.tile(c, 4))[(rows != NONE) & (cols != NONE)]

    def transpose_rows(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows, values) of C^T v."""
        rows, vals = np.concatenate([self.rows_u, self.rows_l]), np.concatenate([v, -v])
        keep = rows != NONE
        return rows[keep], vals[keep]


def contact_nodes(comm, pairs: list[ContactPair], need: np.ndarray, images: list[np.ndarray],
                  mould: MouldRows | None = None, packing=None) -> Nodes:
    """One constraint per (pair, node) of the overlaps: the gap at least the node's margin (the
    P2 field's overstatement of the model's gap around it). A periodic image (a dof on the right
    or top side, the slave of one on the left or bottom) is the same constraint as its master's
    and is left out. A node seen by several ranks (it lies on the cells of the pair they hold)
    is given to one of them (`_claim`): the set of constraints, like the unknowns, does not depend
    on the partition. images[i]: yarn i's dofs that are images (bool over its local dofs).
    Then the mould's constraints, if any, and the maximum packing's (flattening.PackingRows; their
    unknowns must be in `need`)."""
    seen = [np.flatnonzero(~images[p.upper][p.dofs]) for p in pairs]
    key = np.concatenate([k + len(pairs) * p.parent[at] for k, (p, at) in enumerate(zip(pairs, seen))]
                         + [np.zeros(0, np.int64)])  # (pair, parent dof) as one number
    owner = np.concatenate([p.owner[at] for p, at in zip(pairs, seen)] + [np.zeros(0, np.int32)])
    take = np.split(_claim(comm, key, owner), np.cumsum([len(at) for at in seen])[:-1]) if pairs else []
    parts = []
    for k, (p, at, mine) in enumerate(zip(pairs, seen, take)):
        at = at[mine]
        parts.append((np.full(len(at), k), at, p.at_u[at], p.at_l[at], need[p.at_u[at]], need[p.at_l[at]],
                      p.g0[at] - p.margin[at]))
    if mould is not None:
        slot, at = len(need), np.searchsorted(need, mould.unknown)
        bottom = mould.sign > 0
        none = np.full(len(at), NONE, np.int64)
        parts.append((none, none, np.where(bottom, at, slot), np.where(bottom, slot, at),
                      np.where(bottom, mould.unknown, NONE), np.where(bottom, NONE, mould.unknown), mould.g0))
    if packing is not None:
        mark = np.full(len(packing.g0), PACKING, np.int64)
        parts.append((mark, mark, np.searchsorted(need, packing.top), np.searchsorted(need, packing.bottom),
                      packing.top, packing.bottom, packing.g0))
    empty = (np.zeros(0, np.int64),) * 6 + (np.zeros(0),)
    pair, at, at_u, at_l, rows_u, rows_l, g0 = (np.concatenate(a) for a in zip(*(parts or [empty])))
    return Nodes(pair.astype(np.int64), at.astype(np.int64), at_u.astype(np.int64), at_l.astype(np.int64),
                 rows_u.astype(np.int64), rows_l.astype(np.int64), g0.astype(float))


def renewed_nodes(ms: MidSurfaces, numbering: Periodicity, nodes: Nodes, pairs: list[ContactPair],
                  mould: Mould | None, min_gap: float = 0.0) -> Nodes:
    """The same constraints after the pairs' initial gaps and margins were read again (`pairs`,
    the same pairs with new g0 and margin) and, with a mould, its platens' gaps (they may have
    moved); the maximum packing's are kept [mm]."""
    g0 = nodes.g0.copy()
    paired = nodes.pair >= 0
    gaps = np.concatenate([p.g0 - p.margin for p in pairs] + [np.zeros(0)])
    first = np.concatenate([[0], np.cumsum([len(p.g0) for p in pairs])])
    g0[paired] = gaps[first[nodes.pair[paired]] + nodes.at[paired]]
    if mould is not None:
        images = numbering.image_dofs(ms)
        g0[nodes.pair == NONE] = mould_rows(ms, numbering, images, mould, min_gap).g0
    return replace(nodes, g0=g0)


def _claim(comm, key: np.ndarray, owner: np.ndarray) -> np.ndarray:
    """Which of this rank's keys (distinct on it; a key may be on several ranks) it takes, so that
    each key is taken by one rank: the owner given for it if the owner holds it, else the
    lowest-ranked rank that does. Two exchanges with the owners."""
    me = comm.rank
    take = owner == me
    if comm.size == 1:
        return take
    asked = comm.alltoall([key[owner == r] if r != me else key[:0] for r in range(comm.size)])
    rank = np.concatenate([np.full(len(a), r, np.int64) for r, a in enumerate(asked)])
    wanted = np.concatenate(asked)
    unheld = ~np.isin(wanted, key[take])
    wanted, rank = wanted[unheld], rank[unheld]
    order = np.lexsort((rank, wanted))  # by key, then rank: the first of each key is its lowest holder
    first = order[np.r_[True, wanted[order][1:] != wanted[order][:-1]]] if len(order) else order
    given = comm.alltoall([wanted[first][rank[first] == r] for r in range(comm.size)])
    return take | np.isin(key, np.concatenate(given))
