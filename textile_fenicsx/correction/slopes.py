"""Thickness that follows the slope: a yarn keeps its section (its fibres) normal to its path, so
its vertical thickness is the section's height over cos(slope). The plates are solved with the
initial vertical thickness t0; once the mid-surfaces have moved, t = t0 cos(theta0) / cos(theta)
with the slopes theta0 of z0 and theta of z0 + w along the fibre where that is thicker, t0 where it
would be thinner, and the plates are solved again with it (pipeline.run). The corrected yarns lay
their sections along the centreline's slope, which at a yarn's flanks need not follow the
mid-surface's own: where the rule thinned a plate the corrected yarn could be thicker than its
plate (satin4 h0.3: plates 2 % thinner at a flank than the corrected yarn, which overlapped its
neighbour 0.009 mm deep); never thinning leaves the corrected yarns inside the columns the plates
reserved for them (the satins of the sweep: depth 0.006-0.009 -> <= 0.0007 mm, thickness +0.3-0.6 %)."""

import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
from textile_fenicsx.plate.mesh.midsurface import MidSurface

__all__ = ["slope_thickness"]

def _slope(y: MidSurface, z) -> dolfinx.fem.Function:
    """The L2 projection of the slope along the fibre, d . grad z, onto the yarn's P2 space."""
    u, v = ufl.TrialFunction(y.V), ufl.TestFunction(y.V)
    d = y.d / ufl.sqrt(ufl.dot(y.d, y.d))
    a, L = dolfinx.fem.form(u * v * y.dx), dolfinx.fem.form(ufl.dot(d, ufl.grad(z)) * v * y.dx)
    A = dolfinx.fem.petsc.assemble_matrix(a)
    A.assemble()
    b = dolfinx.fem.petsc.assemble_vector(L)
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    # dofs of the ghost strip carry no mass (dx is over the cell's own cells): keep them at 0
    diag = A.getDiagonal()
    empty = diag.getArray() == 0
    diag.destroy()
    A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
    for i in np.flatnonzero(empty):
        row = A.getOwnershipRange()[0] + i
        A.setValue(row, row, 1.0)
    A.assemble()
    s = dolfinx.fem.Function(y.V)
    ksp = PETSc.KSP().create(y.mesh.comm)
    ksp.setOperators(A)
    ksp.setType("cg")
    ksp.getPC().setType("jacobi")
    ksp.setTolerances(rtol=1e-12, atol=1e-14)
    ksp.solve(b, s.x.petsc_vec)
    s.x.scatter_forward()
    for obj in (ksp, A, b):
        obj.destroy()
    return s


def slope_thickness(ms, w: list) -> float:
    """Set every yarn's thickness to max(t0 cos(theta0) / cos(theta), t0) (module docstring); returns
    the largest relative change (collective)."""
    worst = 0.0
    for y, wi in zip(ms.yarns, w):
        if not hasattr(y, "t_initial"):
            y.t_initial = y.t.x.array.copy()
        s0 = _slope(y, y.z0)
        z = dolfinx.fem.Function(y.V)
        z.x.array[:] = y.z0.x.array + wi.x.array
        s1 = _slope(y, z)
        factor = np.maximum(np.sqrt(1 + s1.x.array**2) / np.sqrt(1 + s0.x.array**2), 1.0)
        y.t.x.array[:] = y.t_initial * factor
        worst = max(worst, float(np.max(np.abs(factor - 1), initial=0.0)))
    return ms.V.mesh.comm.allreduce(worst, op=MPI.MAX)
