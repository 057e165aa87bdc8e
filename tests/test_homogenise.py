"""Periodic homogenisation against closed forms (DESIGN.md section 12; homogenise/).

Small boxes (create_box, hexahedra and tetrahedra, Q2/P2), phases from cell midpoints, so that the
same cell is built on any number of ranks.
"""

import json

import numpy as np
import pytest
from mpi4py import MPI
from test_materials import PATCH, rotation, tensor_rotation

import dolfinx
import dolfinx.fem
from textile_fenicsx.common.errors import FormatError, GeometryError, SolverError, TextileError
from textile_fenicsx.homogenisation import (
    HomogeniseOptions,
    Isotropic,
    Orthotropic,
    homogenise,
    homogenise_fields,
    phase_fields,
    yarn_material,
)
from textile_fenicsx.homogenisation.cellproblem import CG_GAMG, CG_PMG, cell_measure, default_solver
from textile_fenicsx.homogenisation.effective import _nodes
from textile_fenicsx.homogenisation.materials import PRESETS, stiffness
from textile_fenicsx.homogenisation.periodic import bounding_box, check_one_master, periodic_constraint

CELLS = {"hex": dolfinx.mesh.CellType.hexahedron, "tet": dolfinx.mesh.CellType.tetrahedron}
YARN = yarn_material(PRESETS["t300"], PRESETS["epoxy"], 0.6)
EPOXY = PRESETS["epoxy"]


def box_cell(comm, kind="hex", n=(3, 3, 3), L=(2.0, 2.0, 1.0), tag=None, direction=None, vf=0.6):
    """mesh, cell tags, DG0 direction and Vf from functions of the cell midpoints (n, 3)."""
    msh = dolfinx.mesh.create_box(comm, [[0.0, 0.0, 0.0], list(L)], list(n), CELLS[kind])
    imap = msh.topology.index_map(3)
    cells = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
    mid = dolfinx.mesh.compute_midpoints(msh, 3, cells)
    tags = np.zeros(len(cells), np.int32) if tag is None else tag(mid).astype(np.int32)
    a = np.tile([1.0, 0.0, 0.0], (len(cells), 1)) if direction is None else direction(mid, tags)
    W3 = dolfinx.fem.functionspace(msh, ("DG", 0, (3,)))
    W = dolfinx.fem.functionspace(msh, ("DG", 0))
    d, v = dolfinx.fem.Function(W3, name="direction"), dolfinx.fem.Function(W, name="yarn_vf")
    d.x.array.reshape(-1, 3)[W3.dofmap.list[:, 0]] = a
    v.x.array[W.dofmap.list[:, 0]] = np.where(tags > 0, vf, 0.0)
    return msh, dolfinx.mesh.meshtags(msh, 3, cells, tags), d, v


def scramble(mid):
    """A pseudo-random number in [0, 1) per point, the same on any partition."""
    return np.modf(np.abs(np.sin(mid @ np.array([12.9898, 78.233, 37.719])) * 43758.5453))[0]


def relative(A, B):
    return np.abs(np.asarray(A) - np.asarray(B)).max() / np.abs(np.asarray(B)).max()


def backus_z(layers):
    """Exact stiffness of a medium layered normal to z, [(fraction, C)]: in-plane strains (11, 22, 12)
    and out-of-plane stresses (33, 23, 13) are the same in every layer."""
    I, O = [0, 1, 5], [2, 3, 4]

    def avg(f):
        return sum(w * f(C) for w, C in layers)

    inv = {id(C): np.linalg.inv(C[np.ix_(O, O)]) for _, C in layers}
    A_OO = np.linalg.inv(avg(lambda C: inv[id(C)]))
    right = avg(lambda C: inv[id(C)] @ C[np.ix_(O, I)])
    A = np.zeros((6, 6))
    A[np.ix_(O, O)] = A_OO
    A[np.ix_(O, I)] = A_OO @ right
    A[np.ix_(I, O)] = (A_OO @ right).T
    A[np.ix_(I, I)] = (avg(lambda C: C[np.ix_(I, I)] - C[np.ix_(I, O)] @ inv[id(C)] @ C[np.ix_(O, I)])
                       + right.T @ A_OO @ right)
    return A


@pytest.mark.mpi
@pytest.mark.parametrize("kind", ["hex", "tet"])
def test_every_slave_has_one_master_off_the_plus_faces(kind):
    msh = dolfinx.mesh.create_box(MPI.COMM_WORLD, [[0, 0, 0], [2.0, 1.0, 1.0]], [3, 2, 2], CELLS[kind])
    import basix.ufl

    V = dolfinx.fem.functionspace(msh, basix.ufl.element("Lagrange", msh.basix_cell(), 2, shape=(3,)))
    box = bounding_box(msh)
    assert 3 * _nodes(msh, 2) == V.dofmap.index_map.size_global * 3  # the memory estimate's count
    mpc = periodic_constraint(V, box)
    # P2/Q2 dofs on the + faces: (n+1)-grids of half-cells minus the - faces' copies
    nodes = {"hex": (7 * 5 * 5) - (6 * 4 * 4), "tet": (7 * 5 * 5) - (6 * 4 * 4)}[kind]
    assert check_one_master(mpc) == 3 * nodes
    # the master of each owned slave is the dof at the slave's location with every + coordinate
    # wrapped, never on a + face (masters may be another rank's: compare global indices)
    imap, bs = V.dofmap.index_map, 3
    x = V.tabulate_dof_coordinates()[: imap.size_local]
    owned_global = imap.local_to_global(np.arange(imap.size_local, dtype=np.int32))
    every_x = np.concatenate(msh.comm.allgather(x))
    every_global = np.concatenate(msh.comm.allgather(owned_global))
    slaves = np.asarray(mpc.slaves)
    slaves = slaves[slaves < imap.size_local * bs]
    masters = np.asarray(mpc.masters.array)[np.asarray(mpc.masters.offsets)[slaves]]
    mimap = mpc.function_space.dofmap.index_map
    master_global = mimap.local_to_global((masters // bs).astype(np.int32))
    xs = x[slaves // bs]
    wrapped = np.where(np.abs(xs - box.hi) < box.tol, xs - box.size, xs)
    nearest = np.argmin(np.linalg.norm(every_x[None, :, :] - wrapped[:, None, :], axis=2), axis=1)
    assert np.allclose(every_x[nearest], wrapped, atol=1e-12)
    assert np.array_equal(every_global[nearest], master_global)
    assert not np.any(np.abs(every_x[nearest] - box.hi) < box.tol)
    assert np.all(slaves % bs == masters % bs)


@pytest.mark.mpi
def test_one_master_per_slave_far_from_the_origin():
    # masters are matched by location, not by evaluating basis functions at the image (whose
    # rounding gave some nodes a second master of ~1e-13 on a 600k-dof box of 11.2 mm)
    import basix.ufl

    msh = dolfinx.mesh.create_box(MPI.COMM_WORLD, [[1e3, 1e3, 1e3], [1011.2, 1011.2, 1001.0]], [12, 12, 2],
                                  CELLS["tet"])
    V = dolfinx.fem.functionspace(msh, basix.ufl.element("Lagrange", msh.basix_cell(), 2, shape=(3,)))
    mpc = periodic_constraint(V, bounding_box(msh))
    assert check_one_master(mpc) == 3 * (25 * 25 * 5 - 24 * 24 * 4)


@pytest.mark.mpi
def test_a_mesh_whose_faces_do_not_match_is_refused():
    msh, tags, d, v = box_cell(MPI.COMM_WORLD)
    x = msh.geometry.x
    inside_face = np.isclose(x[:, 0], 2.0) & (x[:, 1] > 0.1) & (x[:, 1] < 1.9) & (x[:, 2] > 0.1) & (x[:, 2] < 0.9)
    x[inside_face, 1] += 0.05
    with pytest.raises(GeometryError, match="not periodic"):
        homogenise(msh, tags, d, v, EPOXY, EPOXY)


@pytest.mark.mpi
@pytest.mark.parametrize("kind", ["hex", "tet"])
def test_yarns_of_the_matrix_give_the_matrix(kind):
    # fibre = matrix: every yarn cell (random tags and directions, Vf 0.6) is the matrix again
    msh, tags, d, v = box_cell(MPI.COMM_WORLD, kind, tag=lambda m: (scramble(m) > 0.5) * (1 + (m[:, 2] > 0.5)),
                               direction=lambda m, t: np.stack([scramble(m), 1 - scramble(m), 0.3 + 0 * m[:, 0]], 1))
    r = homogenise(msh, tags, d, v, EPOXY, EPOXY)
    assert relative(r.C, stiffness(EPOXY)) < 1e-8
    assert relative(r.K, 0.2 * np.eye(3)) < 1e-8
    assert r.constants["Ex"] == pytest.approx(3350, rel=1e-8) and r.constants["nuxy"] == pytest.approx(0.35, rel=1e-8)
    assert r.fibre_fraction == pytest.approx(0.6 * r.yarn_fraction)


@pytest.mark.mpi
@pytest.mark.parametrize("kind", ["hex", "tet"])
def test_two_layers_at_0_and_90_degrees_give_the_layered_medium(kind):
    # a third at 0 degrees (fibres along x, z < 1/3), two thirds at 90 (along y)
    msh, tags, d, v = box_cell(MPI.COMM_WORLD, kind, n=(2, 2, 3), tag=lambda m: 1 + (m[:, 2] > 1 / 3),
                               direction=lambda m, t: np.where((t == 1)[:, None], [1.0, 0, 0], [0, 1.0, 0]))
    r = homogenise_fields(phase_fields(msh, tags, d, {1: YARN, 2: YARN}))
    C0 = stiffness(YARN)
    C90 = tensor_rotation(C0, rotation([0, 0, 1], np.pi / 2))
    assert relative(r.C, backus_z([(1 / 3, C0), (2 / 3, C90)])) < 1e-6
    # conduction: parallel in the plane, series across it
    k1, k2 = YARN.k1, YARN.k2
    expected = np.diag([k1 / 3 + 2 * k2 / 3, k2 / 3 + 2 * k1 / 3, 1 / (1 / (3 * k2) + 2 / (3 * k2))])
    assert relative(r.K, expected) < 1e-6


@pytest.mark.mpi
def test_series_and_parallel_conduction_of_isotropic_layers():
    hot, cold = Isotropic("hot", 1e4, 0.3, k=5.0), Isotropic("cold", 2e3, 0.2, k=0.5)
    msh, tags, d, v = box_cell(MPI.COMM_WORLD, "tet", n=(2, 2, 4), tag=lambda m: 1 + (m[:, 2] > 0.25))
    r = homogenise_fields(phase_fields(msh, tags, d, {1: hot, 2: cold}))
    assert relative(r.K, np.diag([5 / 4 + 1.5 / 4, 5 / 4 + 1.5 / 4, 1 / (1 / 20 + 3 / 2)])) < 1e-8
    assert relative(r.C, backus_z([(0.25, stiffness(hot)), (0.75, stiffness(cold))])) < 1e-6


@pytest.mark.mpi
def test_a_rotated_unidirectional_block_gives_the_rotated_stiffness():
    a = np.array([np.cos(0.5) * np.cos(0.3), np.sin(0.5) * np.cos(0.3), np.sin(0.3)])
    msh, tags, d, v = box_cell(MPI.COMM_WORLD, "tet", n=(2, 2, 2), tag=lambda m: 1 + 0 * m[:, 0],
                               direction=lambda m, t: np.tile(a, (len(t), 1)))
    r = homogenise(msh, tags, d, v, PRESETS["t300"], EPOXY)
    # the material frame: e1 = a and any e2 across it (transversely isotropic)
    e2 = np.cross([0, 0, 1.0], a)
    e2 /= np.linalg.norm(e2)
    R = np.stack([a, e2, np.cross(a, e2)], axis=1)
    assert relative(r.C, tensor_rotation(stiffness(YARN), R)) < 1e-8
    assert relative(r.K, YARN.k2 * np.eye(3) + (YARN.k1 - YARN.k2) * np.outer(a, a)) < 1e-8
    assert r.fibre_fraction == pytest.approx(0.6) and r.yarn_fraction == pytest.approx(1.0)


@pytest.mark.mpi
def test_texgen_issue_22_patch_test_returns_the_nine_constants():
    block = Orthotropic("patch", **PATCH)
    msh, tags, d, v = box_cell(MPI.COMM_WORLD, "hex", n=(2, 2, 2))
    r = homogenise_fields(phase_fields(msh, tags, d, {0: block}), HomogeniseOptions(conduction=False))
    expected = {"Ex": 1111, "Ey": 2222, "Ez": 3333, "Gxy": 1212, "Gxz": 1313, "Gyz": 2323, "nuxy": 0.1212,
                "nuxz": 0.1313, "nuyz": 0.2323}
    for name, value in expected.items():
        assert r.constants[name] == pytest.approx(value, rel=1e-8), name
    # TexGen shipped G13 and G23 swapped; the stiffness's 23 entry (4th) is G23, its 13 entry G13
    assert r.C[3, 3] == pytest.approx(2323, rel=1e-8) and r.C[4, 4] == pytest.approx(1313, rel=1e-8)
    assert r.K is None


def two_phase(comm, kind="hex"):
    return box_cell(comm, kind, n=(4, 4, 3), tag=lambda m: (scramble(m) > 0.45) * (1 + (scramble(2 * m) > 0.5)),
                    direction=lambda m, t: np.where((t == 1)[:, None], [1.0, 0.0, 0.2], [0.0, 1.0, -0.2]))


@pytest.mark.mpi
def test_a_random_two_phase_cell_lies_between_the_bounds():
    r = homogenise(*two_phase(MPI.COMM_WORLD), PRESETS["t300"], EPOXY)
    assert r.asymmetry < 1e-12
    assert np.linalg.eigvalsh(r.C).min() > 0
    scale = np.abs(r.C).max()
    assert np.linalg.eigvalsh(r.voigt - r.C).min() > -1e-9 * scale
    assert np.linalg.eigvalsh(r.C - r.reuss).min() > -1e-9 * scale
    assert np.linalg.eigvalsh(r.voigt - r.C).max() > 1e-3 * scale  # not trivially on a bound
    assert np.linalg.eigvalsh(r.K_voigt - r.K).min() > -1e-9 and np.linalg.eigvalsh(r.K - r.K_reuss).min() > -1e-9
    assert all(len(v) == 6 for v in [r.iterations["elasticity"]]) and len(r.iterations["conduction"]) == 3
    record = json.loads(json.dumps(r.to_dict()))
    assert record["voigt_order"] == ["11", "22", "33", "23", "13", "12"] and "engineering" in record["shear"]
    assert record["dofs"]["elasticity"] == 3 * 9 * 9 * 7 and record["units"]["C"] == "MPa"
    assert record["checks"]["min_eig_C"] > 0 and record["checks"]["min_eig_voigt_minus_C"] > -1e-9


def _elastic_matrix(mesh, degree, dx) -> np.ndarray:
    """The values of the elastic cell problem's matrix (a T300 fibre's stiffness, no constraint)."""
    import basix.ufl
    import ufl

    from textile_fenicsx.homogenisation.elasticity_forms import elastic_cell_forms

    V = dolfinx.fem.functionspace(mesh, basix.ufl.element("Lagrange", mesh.basix_cell(), degree, shape=(3,)))
    D = dolfinx.fem.Constant(mesh, stiffness(PRESETS["t300"]))
    a, _ = elastic_cell_forms(ufl.TrialFunction(V), ufl.TestFunction(V), D, dolfinx.fem.Constant(mesh, np.zeros(6)),
                              dx)
    return dolfinx.fem.assemble_matrix(dolfinx.fem.form(a)).data.copy()


@pytest.mark.mpi
@pytest.mark.parametrize("degree", [1, 2])
def test_parallelepipeds_get_the_exact_gauss_rule_and_other_hexes_ufls(degree):
    # on a sheared box (parallelepipeds) the integrand is a polynomial of degree 2 p in each reference
    # coordinate: p + 1 Gauss points a direction are exact, so the matrix is UFL's (more points) to
    # round-off; a bilinear map is not affine and keeps UFL's estimate
    import ufl

    mesh = dolfinx.mesh.create_box(MPI.COMM_WORLD, [[0.0, 0.0, 0.0], [2.0, 2.0, 1.0]], [3, 3, 2],
                                   dolfinx.mesh.CellType.hexahedron)
    x = mesh.geometry.x
    x[:, 0] += 0.3 * x[:, 1] + 0.2 * x[:, 2]
    x[:, 1] += 0.1 * x[:, 2]
    dx = cell_measure(mesh, degree)
    assert dx.metadata() == {"quadrature_degree": 2 * degree}
    exact, estimated = _elastic_matrix(mesh, degree, dx), _elastic_matrix(mesh, degree, ufl.dx(domain=mesh))
    scale = MPI.COMM_WORLD.allreduce(float(np.abs(estimated).max()), op=MPI.MAX)
    worst = MPI.COMM_WORLD.allreduce(float(np.abs(exact - estimated).max()), op=MPI.MAX)
    assert worst < 1e-12 * scale

    x[:, 2] += 0.02 * x[:, 0] * x[:, 1]
    assert cell_measure(mesh, degree).metadata() == {}
    tets = dolfinx.mesh.create_unit_cube(MPI.COMM_WORLD, 2, 2, 2)
    assert cell_measure(tets, degree).metadata() == {}


@pytest.mark.mpi
def test_all_ranks_and_one_rank_agree():
    # under mpirun: the same cell on all ranks together and on each rank alone
    together = homogenise(*two_phase(MPI.COMM_WORLD, "tet"), PRESETS["e-glass"], EPOXY)
    alone = homogenise(*two_phase(MPI.COMM_SELF, "tet"), PRESETS["e-glass"], EPOXY)
    assert relative(together.C, alone.C) < 1e-8
    assert relative(together.K, alone.K) < 1e-8


@pytest.mark.mpi
def test_bad_inputs_name_the_culprit(tmp_path_factory):
    cell = box_cell(MPI.COMM_WORLD, tag=lambda m: 1 + 0 * m[:, 0])
    with pytest.raises(TextileError, match="unknown material 'kevlar'"):
        homogenise(*cell, "kevlar", EPOXY)
    path = tmp_path_factory.mktemp(f"rank{MPI.COMM_WORLD.rank}") / "resin.toml"
    path.write_text('symmetry = "isotropic"\nE = 3000\n')
    with pytest.raises(FormatError, match="resin.toml: isotropic needs nu"):
        homogenise(*cell, "t300", path)
    msh, tags, d, v = cell
    v.x.array[:] = 1.5
    with pytest.raises(TextileError, match="fibre volume fraction outside"):
        homogenise(msh, tags, d, v, "t300", EPOXY)
    with pytest.raises(TextileError, match="would need about"):
        homogenise(*box_cell(MPI.COMM_WORLD), "t300", EPOXY, HomogeniseOptions(memory_limit=1e-6))


@pytest.mark.serial
def test_memory_estimate_by_degree():
    """The guard's estimate bounds the peaks measured (docs/volume.md, refinement study, 2026-11-26): first-
    order voxels on 2 ranks peaked at 2.49 GB (1 166 445 dofs) and 6.62 GB (3 189 375 dofs) in the
    largest process, so at most twice that summed over the ranks; and it no longer takes them at
    the second order's price, which refused the 3.2 million dofs as 29 GB. The sum over ranks grows
    little with them (the voxel satin's 1.25 M Q2 dofs: 6.8 GB on one rank, 3.5 GB a rank on two):
    the estimate on two ranks is not twice the serial one, which refused that grid on two ranks."""
    from textile_fenicsx.homogenisation import estimated_bytes

    for dofs, peak_gb in ((1_166_445, 2.49), (3_189_375, 6.62)):
        first = estimated_bytes(dofs, "hexahedron", 2, degree=1)
        assert 2 * peak_gb * 1e9 <= first < 0.6 * estimated_bytes(dofs, "hexahedron", 2, degree=2)
    serial, two = (estimated_bytes(1_247_505, "hexahedron", ranks) for ranks in (1, 2))
    assert 6.8e9 <= serial and 2 * 3.5e9 <= two < 1.5 * serial, "the satin's peaks bounded, two ranks not twice one"


@pytest.mark.mpi
def test_a_solve_that_does_not_converge_raises():
    solver = dict(CG_GAMG, ksp_max_it=2)
    with pytest.raises(SolverError, match="elasticity cell problem, load case 1: CG did not converge.*DIVERGED_MAX_IT"):
        homogenise(*two_phase(MPI.COMM_WORLD), "t300", EPOXY, HomogeniseOptions(elasticity_solver=solver))


@pytest.mark.mpi
@pytest.mark.parametrize("kind", ["hex", "tet"])
def test_the_degree_1_level_is_the_galerkin_product_of_the_degree_2_problem(kind):
    # a periodic P1 (Q1) field is a periodic P2 (Q2) field on the same mesh and both degrees pin the
    # same vertex, so P^T A_2 P equals the P1 matrix on the free dofs to round-off: the coarse level
    # of the p-multigrid is exact (pmultigrid.py)
    from petsc4py import PETSc

    from textile_fenicsx.homogenisation.elasticity import ElasticCellProblem
    from textile_fenicsx.homogenisation.fields import yarn_fields
    from textile_fenicsx.homogenisation.pmultigrid import prolongation

    msh, tags, d, v = two_phase(MPI.COMM_WORLD, kind)
    fields = yarn_fields(msh, tags, d, v, PRESETS["t300"], EPOXY)
    fine = ElasticCellProblem(fields.D, bounding_box(msh), default_solver(2), 2)
    P = G = free = None
    try:
        coarse = fine.coarse
        assert coarse.V.element.basix_element.degree == 1
        P = prolongation(coarse, fine)
        G = fine.A.ptap(P)
        G.axpy(-1.0, coarse.A, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        free = coarse.A.createVecLeft()
        free.getArray()[:] = np.where(coarse.constrained, 0.0, 1.0)
        G.diagonalScale(free, free)
        scale = coarse.A.norm(PETSc.NormType.FROBENIUS)
        assert G.norm(PETSc.NormType.FROBENIUS) < 1e-12 * scale
    finally:
        for obj in (P, G, free):
            if obj is not None:
                obj.destroy()
        fine.destroy()


@pytest.mark.mpi
def test_p_multigrid_and_gamg_give_the_same_properties():
    cell = two_phase(MPI.COMM_WORLD, "tet")
    pmg = homogenise(*cell, "t300", EPOXY)
    gamg = homogenise(*cell, "t300", EPOXY, HomogeniseOptions(elasticity_solver=dict(CG_GAMG),
                                                            conduction_solver=dict(CG_GAMG)))
    assert relative(pmg.C, gamg.C) < 1e-8 and relative(pmg.K, gamg.K) < 1e-8
    with pytest.raises(ValueError, match="p-multigrid .pc_type mg. needs degree 2"):
        homogenise(*cell, "t300", EPOXY, HomogeniseOptions(degree=1, elasticity_solver=dict(CG_PMG)))
