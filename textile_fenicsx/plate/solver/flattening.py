"""Yarns that flatten (DESIGN.md 5): each yarn's thickness change dt = x_top - x_bottom is held by
its bundle's compaction energy (forms/compression.py), and no yarn is packed beyond phi_max.

Where the yarns flatten, every yarn node has two unknowns, the heights its bottom and its top
surface move by (solver.periodic: surfaces=2): the plates bend with their mid-surface, w = (x_bottom
+ x_top) / 2, a pair's gap reads the upper yarn's bottom and the lower yarn's top, and a mould's
platen the yarn's bottom or top. The compaction energy is not quadratic: the interior point takes
its gradient and Hessian at each iterate (`add_gradient`, `hessian_values`) into the dual residual
and the Newton matrix, as an interior point does for any convex objective; the Hessian is positive
(W'' > 0), so the matrix stays SPD and the factorisation's inertia check still holds. The maximum
packing, t = t0 + dt >= phi0 t0 / phi_max at every node, is one more linear constraint per node
(`packing_rows`): the iterates stay inside it as they stay inside the contact constraints, so W
is only ever evaluated where it is finite.
"""

from dataclasses import dataclass

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
from textile_fenicsx.plate.forms.compression import compaction_forms, compaction_pressure
from textile_fenicsx.plate.mesh.midsurface import MidSurfaces
from textile_fenicsx.plate.solver.numbering import BOTTOM, TOP, Periodicity
from textile_fenicsx.plate.solver.parameters import Compaction

__all__ = ["Flattening", "PackingRows", "fit_margins", "flattening_terms", "law_thickness", "packing_rows",
           "rigid_stack", "thinnest_stack"]


# A plate's thickness falls to 0 at the yarn's edges (the rays graze its section there), where the
# law (W ~ t0^3 / t^2) is 0 / 0: the law reads the thickness as at least this part of the yarn's
# largest. The packing constraint reads the true thickness, so such a node cannot thin below
# phi0 / phi_max of it, and t0 + dt stays positive in the law
THINNEST = 0.02


def law_thickness(y) -> np.ndarray:
    """The relaxed thickness the law reads at yarn y's dofs: its plate's t, at least THINNEST of
    the yarn's largest [mm] (collective)."""
    t = y.t.x.array
    return np.maximum(t, THINNEST * y.mesh.comm.allreduce(float(np.max(t, initial=0.0)), op=MPI.MAX))


@dataclass(frozen=True)
class Flattening:
    """One yarn's compaction term: the scratch thickness change dt, the relaxed thickness t0 (the
    plate's thickness at the start), the compiled forms and the Jacobian's storage."""

    yarn: int
    dt: dolfinx.fem.Function
    t0: dolfinx.fem.Function
    residual: dolfinx.fem.Form
    jacobian: dolfinx.fem.Form
    pressure: dolfinx.fem.Expression
    matrix: dolfinx.la.MatrixCSR
    diagonal: np.ndarray  # where the owned rows' diagonal entries are in the matrix's data
    maps: tuple  # (R_bottom, R_top): the yarn's dofs (owned) -> unknowns

    def fill(self, x: PETSc.Vec) -> None:
        """dt = (R_top - R_bottom) x on the yarn's dofs (ghosts too)."""
        bottom, top = self.maps
        tmp = bottom.createVecLeft()
        bottom.mult(x, tmp)
        top.mult(x, self.dt.x.petsc_vec)
        self.dt.x.petsc_vec.axpy(-1.0, tmp)
        tmp.destroy()
        self.dt.x.scatter_forward()


def flattening_terms(ms: MidSurfaces, numbering: Periodicity, maps: list, compaction: Compaction):
    """Every yarn's compaction term, and the (row, column) unknowns of its Hessian's entries in the
    order `hessian_values` gives them (collective). maps: per yarn (R_bottom, R_top)."""
    terms, rows, cols = [], [], []
    for y, (bottom, top) in zip(ms.yarns, maps):
        msh = y.mesh
        dt = dolfinx.fem.Function(y.V, name="dt")
        t0 = y.t.copy()
        t0.x.array[:] = law_thickness(y)
        c = dolfinx.fem.Constant
        modulus, phi0 = c(msh, float(compaction.modulus)), c(msh, compaction.fraction(y.yarn))
        _, residual, jacobian = compaction_forms(dt, t0, modulus, phi0, y.dx)
        J = dolfinx.fem.form(jacobian)
        M = dolfinx.fem.create_matrix(J)
        n_owned = y.V.dofmap.index_map.size_local
        nnz = int(M.indptr[n_owned])
        # the energy is taken at the nodes (forms/compression.py, NODAL): only the diagonal is not 0
        local_rows = np.repeat(np.arange(n_owned), np.diff(M.indptr[:n_owned + 1]))
        diagonal = np.flatnonzero(M.indices[:nnz] == local_rows)
        pressure = dolfinx.fem.Expression(compaction_pressure(t0 + dt, t0, modulus, phi0),
                                          y.V.element.interpolation_points())
        terms.append(Flattening(y.yarn, dt, t0, dolfinx.fem.form(residual), J, pressure, M, diagonal,
                                (bottom, top)))
        i = numbering.parent_global[y.to_parent[local_rows[diagonal]]]
        ib, it = numbering.unknown(y.yarn, i, BOTTOM), numbering.unknown(y.yarn, i, TOP)
        rows.append(np.concatenate([ib, ib, it, it]))
        cols.append(np.concatenate([ib, it, ib, it]))
    return terms, tuple(np.concatenate(a) if a else np.zeros(0, np.int64) for a in (rows, cols))


def hessian_values(terms: list[Flattening], x: PETSc.Vec) -> np.ndarray:
    """The compaction energy's Hessian entries at x (in flattening_terms' order): the Jacobian of
    each yarn's W(t0 + dt) in dt (diagonal: the energy is taken at the nodes), at (bottom, bottom),
    (bottom, top), (top, bottom), (top, top) with the signs of dt = x_top - x_bottom."""
    parts = [np.zeros(0)]
    for term in terms:
        term.fill(x)
        M = term.matrix
        M.set_value(0.0)
        dolfinx.fem.assemble_matrix(M, term.jacobian)
        M.scatter_reverse()
        m = M.data[term.diagonal]
        parts.append(np.concatenate([m, -m, -m, m]))
    return np.concatenate(parts)


def add_gradient(terms: list[Flattening], x: PETSc.Vec, r: PETSc.Vec) -> None:
    """r += the compaction energy's gradient at x: R_top^T dW - R_bottom^T dW (collective)."""
    for term in terms:
        term.fill(x)
        dW = dolfinx.fem.petsc.assemble_vector(term.residual)
        dW.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        bottom, top = term.maps
        top.multTransposeAdd(dW, r, r)
        dW.scale(-1.0)
        bottom.multTransposeAdd(dW, r, r)
        dW.destroy()


def thickness_changes(terms: list[Flattening], x: PETSc.Vec) -> list[dolfinx.fem.Function]:
    """Per yarn its thickness change dt at x [mm] (new Functions)."""
    out = []
    for term in terms:
        term.fill(x)
        out.append(term.dt.copy())
        out[-1].name = "dt"
    return out


@dataclass(frozen=True)
class PackingRows:
    """The maximum packing's constraints on this rank, one per owned, non-image yarn node:
    g = g0 + x_top - x_bottom >= 0 with g0 = t0 - phi0 t0 / phi_max [mm]."""

    top: np.ndarray     # unknowns (global indices)
    bottom: np.ndarray
    g0: np.ndarray


def packing_rows(ms: MidSurfaces, numbering: Periodicity, images: list[np.ndarray],
                 compaction: Compaction) -> PackingRows:
    """No yarn node denser than the maximum packing (each unknown once over the ranks)."""
    parts = []
    for y, image in zip(ms.yarns, images):
        dofs = np.flatnonzero(~image[:y.V.dofmap.index_map.size_local])
        t0 = y.t.x.array[dofs]
        parts.append((numbering.yarn_unknowns(y, dofs, TOP), numbering.yarn_unknowns(y, dofs, BOTTOM),
                      t0 * (1 - compaction.fraction(y.yarn) / compaction.phi_max)))
    top, bottom, g0 = (np.concatenate(a) for a in zip(*parts))
    return PackingRows(top.astype(np.int64), bottom.astype(np.int64), g0.astype(float))


def thinnest_stack(ms: MidSurfaces, compaction: Compaction) -> tuple[float, tuple[float, float]]:
    """The thinnest the yarns can be pressed: the largest sum, over the yarns stacked at a node, of
    their thickness at the maximum packing, phi0 t0 / phi_max [mm], and where (x, y) [mm]
    (collective; a node's yarns are summed on each rank that holds it, so this bounds the true
    value from below on several ranks)."""
    imap = ms.V.dofmap.index_map
    stack = np.zeros(imap.size_local + imap.num_ghosts)
    for y in ms.yarns:
        np.add.at(stack, y.to_parent, y.t.x.array * compaction.fraction(y.yarn) / compaction.phi_max)
    k = int(np.argmax(stack)) if len(stack) else -1
    mine = (float(stack[k]), tuple(map(float, ms.V.tabulate_dof_coordinates()[k, :2]))) if k >= 0 \
        else (0.0, (np.nan, np.nan))
    return max(ms.V.mesh.comm.allgather(mine), key=lambda m: m[0])



def _stacks(ms: MidSurfaces, min_gap: float, margins: bool = True):
    """Every node's stack of yarns (rigid_stack), gathered over the ranks: (its global index, its
    in-plane position (x, y), the height of its tallest chain [mm]) per node, and the global nodes
    of this rank's pairs (the same order as ms.contact_dofs); margins=False: the pairs' margins
    left out (the least gap kept)."""
    comm, imap = ms.V.mesh.comm, ms.V.dofmap.index_map
    xy = ms.V.tabulate_dof_coordinates()[:, :2]
    position = {y.yarn: k for k, y in enumerate(ms.yarns)}
    nodes, edges, mine = [], [], []  # (yarn, global node, t, x, y); (upper, lower, global node, margin)
    for k, y in enumerate(ms.yarns):
        parent = y.to_parent
        nodes.append(np.column_stack((np.full(len(parent), k), imap.local_to_global(parent.astype(np.int32)),
                                      y.t.x.array[: len(parent)], xy[parent])))
    for (u, l), pairs in ms.contact_dofs.items():
        at = imap.local_to_global(ms.yarns[position[u]].to_parent[pairs[:, 0]].astype(np.int32))
        margin = ms.contact_margin.get((u, l), np.zeros(len(pairs))) if margins else np.zeros(len(pairs))
        edges.append(np.column_stack((np.full(len(pairs), position[u]), np.full(len(pairs), position[l]), at,
                                      margin)))
        mine.append(at)
    node = np.concatenate(comm.allgather(np.concatenate(nodes) if nodes else np.zeros((0, 5))))
    edge = np.concatenate(comm.allgather(np.concatenate(edges) if edges else np.zeros((0, 4))))
    n_global = int(node[:, 1].max()) + 1 if len(node) else 1
    keys, at = np.unique(node[:, 0].astype(np.int64) * n_global + node[:, 1].astype(np.int64), return_inverse=True)
    t = np.zeros(len(keys))
    np.maximum.at(t, at, node[:, 2])
    upper = np.searchsorted(keys, edge[:, 0].astype(np.int64) * n_global + edge[:, 2].astype(np.int64))
    lower = np.searchsorted(keys, edge[:, 1].astype(np.int64) * n_global + edge[:, 2].astype(np.int64))
    gap = edge[:, 3] + min_gap
    height: np.ndarray = t.copy()
    for _ in range(len(ms.yarns)):  # a chain has at most one yarn of each
        below = np.zeros(len(keys))
        np.maximum.at(below, upper, height[lower] + gap)
        grown = t + below
        if np.array_equal(grown, height):
            break
        height = grown
    glob, where, of = np.unique(node[:, 1].astype(np.int64), return_index=True, return_inverse=True)
    tallest = np.zeros(len(glob))
    np.maximum.at(tallest, of, height[at] + 2 * min_gap)
    return glob, node[where, 3:5], tallest, mine


def rigid_stack(ms: MidSurfaces, min_gap: float = 0.0) -> tuple[float, tuple[float, float]]:
    """The thinnest mould that holds the yarns as they are (rigid plates, no flattening): the
    largest, over the mesh nodes, of the yarns stacked there, each its plate's thickness t, with
    each contact pair's margin at the node (midsurface.contact_margin) and min_gap between them and
    at both platens [mm], and where (x, y) [mm]. A pair's constraint and a platen's hold node by
    node (the plates bend between them), so a mould is feasible exactly when it is at least this
    thick: a node's stack is its longest chain of pairs, bottom to top (an upper yarn's height over
    the bottom platen is its t over the highest of the lower yarns' heights plus their margin).
    Collective; the same on any partition: every rank's nodes, pairs and margins are gathered by
    global node (a node seen by two ranks keeps its largest margin)."""
    _, xy, tallest, _ = _stacks(ms, min_gap)
    if not len(tallest):
        return 0.0, (np.nan, np.nan)
    k = int(np.argmax(tallest))
    return float(tallest[k]), (float(xy[k, 0]), float(xy[k, 1]))


def fit_margins(ms: MidSurfaces, thickness: float, min_gap: float = 0.0) -> tuple[int, float]:
    """The contact margins scaled down, node by node, where the yarns stacked there with them are
    thicker than `thickness` [mm] (rigid_stack): at a node whose tallest chain is H with its
    margins and H0 without, every pair's margin there times f = (thickness - H0) / (H - H0) (0 where
    H0 >= thickness), so that every chain through it, t + f m <= (1 - f) H0 + f H, fits. The
    margins keep the P2 gap from overstating the model's between the nodes (midsurface._gap_margins);
    summed down a stack they ask for more than the model's own thickness where the yarns touch
    over whole areas (TexGen's refine packs its sections so). Returns the nodes changed and the
    thickness the stacks need without margins, max H0 [mm] (collective, partition-free)."""
    glob, _, with_margins, mine = _stacks(ms, min_gap)
    _, _, without, _ = _stacks(ms, min_gap, margins=False)
    over = with_margins > thickness
    factor = np.ones(len(glob))
    factor[over] = np.clip((thickness - without[over]) / (with_margins[over] - without[over]), 0.0, 1.0)
    for key, at in zip(ms.contact_dofs, mine):
        if key in ms.contact_margin:
            ms.contact_margin[key] = ms.contact_margin[key] * factor[np.searchsorted(glob, at)]
    return int(np.sum(over)), float(np.max(without, initial=0.0))
