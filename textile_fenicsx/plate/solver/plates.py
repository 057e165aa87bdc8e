"""The plates' part of the energy (DESIGN.md 5, 6): each yarn's bending and tension (with any load
and foundation) assembled on its submesh and reduced to the unknowns, K0 = sum R_i^T A_i R_i and
its load b0 (`assemble_plates`); and the common vertical translation of every yarn, the energy's
null space where there is no foundation and no mould (`Translation`).
"""

from dataclasses import dataclass

import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
from textile_fenicsx.plate.forms import c0ip_bending, foundation, load, tension
from textile_fenicsx.plate.mesh.midsurface import MidSurfaces
from textile_fenicsx.plate.solver.numbering import BOTTOM, TOP, Periodicity, seam_facet_tags
from textile_fenicsx.plate.solver.parameters import PlateParameters
from textile_fenicsx.plate.solver.pattern import FixedPattern

__all__ = ["Translation", "assemble_plates", "common_translation"]


def assemble_plates(ms: MidSurfaces, numbering: Periodicity, pattern: FixedPattern, params: PlateParameters,
                    loads: dict, kf: float) -> tuple[list, PETSc.Vec]:
    """Each yarn's plate matrix into `pattern` (as unknowns), and the maps R_i (per yarn, one per
    surface of unknowns) and the load b0.
    The energies act on z0 + w: their restoring force is -A z0, the assembled matrix times z0
    (the action a(z0, v) as a matrix-vector product; ufl.action took 0.7 s of a satin run). Where
    the yarns flatten, w is the mean of the bottom's and the top's unknowns: A / 4 at each pair of
    them, the load b0 / 2 on each."""
    p = params
    R, b = [], numbering.vector()
    sides = (BOTTOM, TOP)[:numbering.surfaces]
    for y in ms.yarns:
        msh = y.mesh
        dS = ufl.Measure("dS", msh, subdomain_data=seam_facet_tags(y), subdomain_id=1)
        c = dolfinx.fem.Constant
        assert p.Db12 is not None  # PlateParameters sets its default
        Db1, Db2, Db12 = (c(msh, float(v)) for v in (p.Db1, p.Db2, p.Db12))
        u, v = ufl.TrialFunction(y.V), ufl.TestFunction(y.V)
        a = c0ip_bending(u, v, y.d, Db1, Db2, Db12, c(msh, p.alpha), y.dx, dS) \
            + tension(u, v, y.d, c(msh, float(p.sigma1)), y.dx)
        A = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(a))
        A.assemble()
        bi = A.createVecLeft()
        A.mult(y.z0.x.petsc_vec, bi)
        bi.scale(-1.0)
        if y.yarn in loads:  # a number [N/mm^2] or a function of the SpatialCoordinate
            q = loads[y.yarn]
            q = q(ufl.SpatialCoordinate(msh)) if callable(q) else c(msh, float(q))
            f = dolfinx.fem.petsc.assemble_vector(dolfinx.fem.form(load(v, q, y.dx)))
            f.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            bi.axpy(1.0, f)
            f.destroy()
        if kf:
            F = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(foundation(u, v, c(msh, float(kf)), y.dx)))
            F.assemble()
            A.axpy(1.0, F, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            F.destroy()
        indptr, cols, vals = A.getValuesCSR()
        rows = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
        columns = numbering.column_parents(y, cols)
        if len(sides) == 2:
            vals = vals / 4
            bi.scale(0.5)
        for row_side in sides:
            for col_side in sides:
                pattern.add_fixed(numbering.yarn_unknowns(y, rows, row_side),
                                  numbering.unknown(y.yarn, columns, col_side), vals)
        R.append([numbering.yarn_map(y, side) for side in sides])
        for Ri in R[-1]:
            Ri.multTransposeAdd(bi, b, b)
        A.destroy()
        bi.destroy()
    return R, b


@dataclass(frozen=True)
class Translation:
    """The common vertical translation of every yarn. weights: m over the unknowns, m . x the
    area-weighted mean of the mid-surfaces' heights times the area [mm^3]; area: the sum of m
    [mm^2]; free: whether it is the energy's null space (no foundation and no mould), in which
    case unknown `pin` is pinned in every Newton matrix and the solution is shifted to zero mean.
    The weights are the problem's to destroy."""

    comm: MPI.Comm
    weights: PETSc.Vec
    area: float
    free: bool

    @property
    def pin(self) -> int | None:
        """The unknown pinned in the Newton matrices (its row and column those of the identity), or None."""
        return 0 if self.free else None

    def motion(self, dx: PETSc.Vec) -> float:
        """The largest |dx| less the common translation (its area-weighted mean), which moves no
        yarn against another and depends on which unknown is pinned: on the partition [mm]."""
        mean = self.weights.dot(dx) / self.area if self.free else 0.0
        local = dx.getArray(readonly=True)
        return self.comm.allreduce(float(np.max(np.abs(local - mean))) if len(local) else 0.0, op=MPI.MAX)

    def remove(self, x: PETSc.Vec) -> None:
        """Shift x to zero area-weighted mean, where the translation is free (in place)."""
        if self.free:
            x.shift(-self.weights.dot(x) / self.area)


def common_translation(ms: MidSurfaces, numbering: Periodicity, R: list, b: PETSc.Vec, kf: float,
                       moulded: bool) -> Translation:
    """The common vertical translation, the energy's null space when there is no foundation (kf
    [N/mm^3]) and no mould: the net load of b is spread over the area (in place; the reaction a
    constraint on the area-weighted mean of w would give), unknown 0 is pinned in every Newton
    matrix, and the solution is shifted to zero mean (`Translation.remove`). R: the maps R_i of
    `assemble_plates`."""
    m = numbering.vector()
    for y, maps in zip(ms.yarns, R):
        mi = dolfinx.fem.petsc.assemble_vector(dolfinx.fem.form(ufl.TestFunction(y.V) * y.dx))
        mi.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        if len(maps) == 2:  # m . x: the area-weighted mean of the mid-surfaces' heights
            mi.scale(0.5)
        for Ri in maps:
            Ri.multTransposeAdd(mi, m, m)
        mi.destroy()
    translation = Translation(ms.V.mesh.comm, m, m.sum(), not kf and not moulded)
    if translation.free:
        b.axpy(-b.sum() / translation.area, m)
    return translation
