"""Manufactured solutions that verify the forms (used by the tests and the demos).

A manufactured solution is a smooth height field z_e chosen in advance; the load that makes it the
exact answer is computed from it symbolically (UFL), so the discrete error and its rate under mesh
refinement measure the discretisation alone.
"""

from dataclasses import dataclass

import numpy as np
import ufl
from mpi4py import MPI

import dolfinx
import dolfinx.fem.petsc
from textile_fenicsx.plate.forms import c0ip_bending, clamped_slope_nitsche, moment
from textile_fenicsx.plate.solver.linear import DIRECT_LU, check_converged


@dataclass(frozen=True)
class AnisotropicPlate:
    """An anisotropic clamped plate on the unit square [0,1]^2 (lengths in mm).

    Db1, Db2, Db12: bending stiffnesses along, across and in twist of the fibre direction [N mm].
    angle_deg: fibre direction, degrees from the x axis. alpha: interior-penalty factor (-).
    """

    Db1: float = 1.0
    Db2: float = 0.2
    Db12: float = 0.3
    angle_deg: float = 30.0
    alpha: float = 3.0

    @staticmethod
    def exact(x, m=ufl):
        """The manufactured deflection: x is a SpatialCoordinate (m=ufl) or an array (m=numpy)."""
        return m.sin(np.pi * x[0]) * m.sin(2 * np.pi * x[1]) + x[0] ** 3 * x[1] / 4


@dataclass(frozen=True)
class PlateSolution:
    """What one solve of the manufactured problem gives."""

    w: dolfinx.fem.Function
    h: float
    error_L2: float
    dofs: int


def solve_manufactured_plate(case: AnisotropicPlate, n: int, degree: int = 2,
                             comm: MPI.Comm = MPI.COMM_WORLD) -> PlateSolution:
    """Solve the clamped anisotropic plate on an n x n mesh and measure the L2 error against z_e."""
    msh = dolfinx.mesh.create_unit_square(comm, n, n, ghost_mode=dolfinx.mesh.GhostMode.shared_facet)
    V = dolfinx.fem.functionspace(msh, ("Lagrange", degree))
    x = ufl.SpatialCoordinate(msh)
    theta = np.deg2rad(case.angle_deg)
    d = ufl.as_vector((np.cos(theta), np.sin(theta)))
    c = dolfinx.fem.Constant
    Db1, Db2, Db12, alpha = (c(msh, float(v)) for v in (case.Db1, case.Db2, case.Db12, case.alpha))

    w_e = case.exact(x)
    f = ufl.div(ufl.div(moment(w_e, d, Db1, Db2, Db12)))
    slope = ufl.dot(ufl.grad(w_e), ufl.FacetNormal(msh))

    w, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    dx = ufl.Measure("dx", msh, metadata={"quadrature_degree": 2 * degree + 2})
    dS = ufl.Measure("dS", msh)
    ds = ufl.Measure("ds", msh)
    a = c0ip_bending(w, v, d, Db1, Db2, Db12, alpha, dx, dS)
    a_b, L_b = clamped_slope_nitsche(w, v, d, Db1, Db2, Db12, alpha, ds, slope)
    L = f * v * dx + L_b

    msh.topology.create_connectivity(1, 2)
    boundary = dolfinx.mesh.exterior_facet_indices(msh.topology)
    w_bc = dolfinx.fem.Function(V)
    w_bc.interpolate(lambda X: case.exact(X, np))
    bc = dolfinx.fem.dirichletbc(w_bc, dolfinx.fem.locate_dofs_topological(V, 1, boundary))

    problem = dolfinx.fem.petsc.LinearProblem(a + a_b, L, bcs=[bc], petsc_options=DIRECT_LU)
    wh = problem.solve()
    check_converged(problem.solver, "clamped plate")
    wh.name = "w"

    err = dolfinx.fem.form((wh - w_e) ** 2 * ufl.dx(msh, metadata={"quadrature_degree": 8}))
    error = np.sqrt(comm.allreduce(dolfinx.fem.assemble_scalar(err), op=MPI.SUM))
    dofs = V.dofmap.index_map.size_global * V.dofmap.index_map_bs
    return PlateSolution(w=wh, h=1.0 / n, error_L2=float(error), dofs=dofs)


def convergence_rates(h, errors):
    """Observed orders log(e_i/e_{i+1}) / log(h_i/h_{i+1}) between successive meshes."""
    h, e = np.asarray(h, float), np.asarray(errors, float)
    return np.log(e[:-1] / e[1:]) / np.log(h[:-1] / h[1:])


def solve_fibre_jump_plate(n: int, Db1: float = 1.0, Db2: float = 0.25,
                           comm: MPI.Comm = MPI.COMM_WORLD) -> PlateSolution:
    """A clamped unit square whose fibres turn from x (x < 1/2) to y (x > 1/2) across a mesh line.

    With the moment M(x) = sin(pi x) the plate bends in x only: w'' = M / D(x), D = Db1 then Db2,
    and w(x) = -sin(pi x) / (pi^2 D(x)) + [x > 1/2] (1/Db2 - 1/Db1) / pi^2 keeps w and w' continuous
    at the jump, where the moment and shear are continuous too; the load is f = M'' = -pi^2 sin(pi x).
    The direction field d is DG0 and jumps between cells: the discrete error must still fall as h^2.
    """
    msh = dolfinx.mesh.create_unit_square(comm, n, n, ghost_mode=dolfinx.mesh.GhostMode.shared_facet)
    V = dolfinx.fem.functionspace(msh, ("Lagrange", 2))
    W = dolfinx.fem.functionspace(msh, ("DG", 0, (2,)))
    d = dolfinx.fem.Function(W)
    d.interpolate(lambda X: np.vstack((np.where(X[0] < 0.5, 1.0, 0.0), np.where(X[0] < 0.5, 0.0, 1.0))))
    x = ufl.SpatialCoordinate(msh)
    right = ufl.gt(x[0], 0.5)
    D = ufl.conditional(right, Db2, Db1)
    w_e = -ufl.sin(np.pi * x[0]) / (np.pi**2 * D) + ufl.conditional(right, (1 / Db2 - 1 / Db1) / np.pi**2, 0.0)
    slope = ufl.dot(ufl.as_vector((ufl.cos(np.pi * x[0]) / (np.pi * D), 0.0)) * -1, ufl.FacetNormal(msh))
    f = -np.pi**2 * ufl.sin(np.pi * x[0])
    c = dolfinx.fem.Constant
    Db12 = (Db1 + Db2) / 4
    k1, k2, k12, alpha = (c(msh, float(v)) for v in (Db1, Db2, Db12, 3.0))
    w, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    dx = ufl.Measure("dx", msh, metadata={"quadrature_degree": 6})
    a = c0ip_bending(w, v, d, k1, k2, k12, alpha, dx, ufl.Measure("dS", msh))
    a_b, L_b = clamped_slope_nitsche(w, v, d, k1, k2, k12, alpha, ufl.Measure("ds", msh), slope)
    msh.topology.create_connectivity(1, 2)
    boundary = dolfinx.mesh.exterior_facet_indices(msh.topology)
    w_bc = dolfinx.fem.Function(V)
    w_bc.interpolate(lambda X: -np.sin(np.pi * X[0]) / (np.pi**2 * np.where(X[0] > 0.5, Db2, Db1))
                     + np.where(X[0] > 0.5, (1 / Db2 - 1 / Db1) / np.pi**2, 0.0))
    bc = dolfinx.fem.dirichletbc(w_bc, dolfinx.fem.locate_dofs_topological(V, 1, boundary))
    problem = dolfinx.fem.petsc.LinearProblem(a + a_b, f * v * dx + L_b, bcs=[bc], petsc_options=DIRECT_LU)
    wh = problem.solve()
    check_converged(problem.solver, "fibre-jump plate")
    err = dolfinx.fem.form((wh - w_e) ** 2 * ufl.dx(msh, metadata={"quadrature_degree": 8}))
    error = np.sqrt(comm.allreduce(dolfinx.fem.assemble_scalar(err), op=MPI.SUM))
    return PlateSolution(w=wh, h=1.0 / n, error_L2=float(error), dofs=V.dofmap.index_map.size_global)
