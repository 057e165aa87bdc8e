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

__all__ = ["Flattening", "PackingRows", "flattening_terms", "law_thickness", "packing_rows", "thinnest_stack"]


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
