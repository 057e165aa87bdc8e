"""C0 interior-penalty anisotropic plate: a manufactured solution converges at the known rate."""

import numpy as np
import pytest

from textile_fenicsx.plate.verification import AnisotropicPlate, convergence_rates, solve_manufactured_plate


@pytest.mark.mpi
def test_c0ip_anisotropic_rotated_plate_converges_at_rate_2():
    # P2 C0IP: the L2 error falls as h^2 (Brenner & Sung 2005; DESIGN.md section 5).
    case = AnisotropicPlate(Db1=1.0, Db2=0.2, Db12=0.3, angle_deg=30.0)
    sols = [solve_manufactured_plate(case, n) for n in (16, 32, 64)]
    rates = convergence_rates([s.h for s in sols], [s.error_L2 for s in sols])
    assert np.all(rates >= 1.8), rates
    assert sols[-1].error_L2 < 1.2e-3  # 1.05e-3 with alpha = 3 and the facet-based h_F (issue 13)


@pytest.mark.mpi
def test_isotropic_plate_is_rotation_invariant():
    # With Db1 = Db2 = D and Db12 = D/2 the energy is D/2 |H|^2, whatever the fibre direction.
    base = AnisotropicPlate(Db1=1.0, Db2=1.0, Db12=0.5, angle_deg=0.0)
    turned = AnisotropicPlate(Db1=1.0, Db2=1.0, Db12=0.5, angle_deg=57.0)
    a, b = solve_manufactured_plate(base, 8), solve_manufactured_plate(turned, 8)
    assert np.allclose(a.w.x.array, b.w.x.array, rtol=0, atol=1e-10)


@pytest.mark.mpi
def test_anisotropy_matters():
    # Guard against a frame that is ignored: rotating an anisotropic plate changes the discrete answer
    # on a coarse mesh, while both converge to the same manufactured field.
    a = solve_manufactured_plate(AnisotropicPlate(angle_deg=0.0), 8)
    b = solve_manufactured_plate(AnisotropicPlate(angle_deg=60.0), 8)
    assert np.max(np.abs(a.w.x.array - b.w.x.array)) > 1e-4


def _sliver_mesh(comm, n=8, width=0.004):
    """The unit square in n x n squares cut into triangles, with one column of squares squeezed to
    `width`: its triangles have a smallest angle of atan(width * n) (1.8 degrees here)."""
    import ufl
    from basix.ufl import element

    import dolfinx

    xs = np.sort(np.concatenate([np.linspace(0, 1, n + 1), [0.5 + width]]))
    xs = xs[xs != 0.5 + 1 / n] if 0.5 + 1 / n in xs else xs
    ys = np.linspace(0, 1, n + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    points = np.column_stack((X.ravel(), Y.ravel()))
    ny = len(ys)
    cells = []
    for i in range(len(xs) - 1):
        for j in range(ny - 1):
            a, b, c, d = i * ny + j, (i + 1) * ny + j, (i + 1) * ny + j + 1, i * ny + j + 1
            cells += [[a, b, c], [a, c, d]]
    if comm.rank != 0:
        points, cells = np.zeros((0, 2)), np.zeros((0, 3), np.int64)
    domain = ufl.Mesh(element("Lagrange", "triangle", 1, shape=(2,)))
    partitioner = dolfinx.mesh.create_cell_partitioner(dolfinx.mesh.GhostMode.shared_facet)
    return dolfinx.mesh.create_mesh(comm, np.asarray(cells, np.int64), points, domain, partitioner=partitioner)


def _negative_pivots(msh, penalty_by_cell_diameter: bool) -> int:
    import ufl
    from petsc4py import PETSc

    import dolfinx
    import dolfinx.fem.petsc
    from textile_fenicsx.plate.forms import c0ip_bending, foundation
    from textile_fenicsx.plate.solver import PlateParameters
    from textile_fenicsx.plate.solver.linear import DIRECT_LDLT, DirectSolver, negative_pivots

    V = dolfinx.fem.functionspace(msh, ("Lagrange", 2))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    d = ufl.as_vector((1.0, 0.0))
    one, alpha = dolfinx.fem.Constant(msh, 1.0), dolfinx.fem.Constant(msh, PlateParameters().alpha)
    dx, dS = ufl.Measure("dx", msh), ufl.Measure("dS", msh)
    a = c0ip_bending(u, v, d, one, one, one / 2, alpha, dx, dS) + foundation(u, v, dolfinx.fem.Constant(msh, 1e-3), dx)
    if penalty_by_cell_diameter:  # the former penalty, alpha D / h_F with h_F from the cell diameters
        n, h = ufl.FacetNormal(msh), ufl.CellDiameter(msh)
        h_F = 2 * h("+") * h("-") / (h("+") + h("-"))
        inv_h = ufl.avg(ufl.FacetArea(msh) / ufl.CellVolume(msh))
        def jump(w):
            return ufl.jump(ufl.grad(w), n)

        a = a + alpha * (1 / h_F - inv_h) * jump(u) * jump(v) * dS
    A = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(a))
    A.assemble()
    solver = DirectSolver(msh.comm, DIRECT_LDLT, prefix="tfx_test")
    solver.factor(A)
    count = negative_pivots(solver.ksp)
    solver.destroy()
    A.destroy()
    PETSc.garbage_cleanup()
    return count


@pytest.mark.mpi
def test_bending_matrix_stays_positive_on_sliver_cells():
    # plate bending + a weak foundation is positive definite: its LDL^T must have no negative pivot
    # (MUMPS' INFOG(12), exact on any number of ranks with ICNTL(13) = 1). With 1.8-degree slivers
    # the former penalty (cell diameters) lost coercivity; the facet-based one (cell areas over the
    # facet's length) keeps it.
    from mpi4py import MPI

    msh = _sliver_mesh(MPI.COMM_WORLD)
    assert _negative_pivots(msh, penalty_by_cell_diameter=False) == 0
    assert _negative_pivots(msh, penalty_by_cell_diameter=True) > 0
