"""The flow stage (textile_fenicsx/flow): the permeability of a periodic cell by Stokes-Brinkman cell
problems, checked against closed forms: Poiseuille flow between plates (exact for Taylor-Hood), a
Brinkman layer beside a free one, a homogeneous porous block at any orientation, Gebart's laws; and
against the literature: flow across a square array of cylinders (gmsh's mesh, flow_cells.py)."""

import json

import numpy as np
import pytest
from flow_cells import cylinder_cell
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.flow import gebart
from textile_fenicsx.flow.effective import MM2_TO_M2, PermeabilityOptions, permeability, yarn_permeability
from textile_fenicsx.flow.problem import DIRECT, ITERATIVE, ITERATIVE_AMG, FlowCellProblem
from textile_fenicsx.homogenisation.periodic import bounding_box
from textile_fenicsx.volume.files import VolumeFields

CELLS = {"tet": dolfinx.mesh.CellType.tetrahedron, "hex": dolfinx.mesh.CellType.hexahedron}


def layered_fields(kind: str, n: tuple[int, int, int], size=(1.0, 1.0, 1.0), porous_below: float = 0.0,
                   direction=(1.0, 0.0, 0.0), vf: float = 0.5, comm=MPI.COMM_WORLD) -> VolumeFields:
    """A box meshed n[0] x n[1] x n[2], its cells below z = porous_below a yarn (phase 1) of fibre
    fraction vf along `direction`, the rest pores (phase 0)."""
    msh = dolfinx.mesh.create_box(comm, [[0.0, 0.0, 0.0], list(size)], list(n), CELLS[kind])
    imap = msh.topology.index_map(3)
    cells = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
    yarn = dolfinx.mesh.compute_midpoints(msh, 3, cells)[:, 2] < porous_below
    owned = np.arange(imap.size_local, dtype=np.int32)
    tags = dolfinx.mesh.meshtags(msh, 3, owned, yarn[owned].astype(np.int32))
    V3 = dolfinx.fem.functionspace(msh, ("DG", 0, (3,)))
    W = dolfinx.fem.functionspace(msh, ("DG", 0))
    d, f = dolfinx.fem.Function(V3), dolfinx.fem.Function(W)
    a = np.asarray(direction, float) / np.linalg.norm(direction)
    d.x.array.reshape(-1, 3)[V3.dofmap.list[cells, 0]] = np.where(yarn[:, None], a, 0.0)
    f.x.array[W.dofmap.list[cells, 0]] = np.where(yarn, vf, 0.0)
    return VolumeFields(msh, tags, d, f)


def test_gebart_laws():
    # along: 8 r^2 / 53 (1 - Vf)^3 / Vf^2; across: 16 / (9 pi sqrt 6) (sqrt(Vmax / Vf) - 1)^2.5 r^2
    r, vf = 0.0035, 0.6
    assert gebart.axial(vf, r) == pytest.approx(8 * r**2 / 53 * 0.4**3 / 0.36, rel=1e-14)
    assert gebart.transverse(vf, r) == pytest.approx(16 / (9 * np.pi * np.sqrt(6)) * (np.sqrt(
        np.pi / (2 * np.sqrt(3)) / vf) - 1) ** 2.5 * r**2, rel=1e-14)
    assert gebart.transverse(gebart.VMAX, r) == 0.0  # the densest packing stops the transverse flow
    assert gebart.axial(0.5, r) > gebart.transverse(0.5, r)  # easier along the fibres
    a = np.array([[0.0, 0.6, 0.8]])
    K = gebart.tensors(a, np.array([3.0]), np.array([1.0]))[0]
    values, vectors = np.linalg.eigh(K)
    assert np.allclose(values, [1.0, 1.0, 3.0]) and np.allclose(np.abs(vectors[:, 2]), a[0])


@pytest.mark.mpi
@pytest.mark.parametrize("kind", ["tet", "hex"])
def test_poiseuille_between_plates_is_exact(kind):
    """An impermeable layer 0.3 thick in a cell 1.0 high, periodic: plane Poiseuille flow in the
    gap h = 0.7 between the layer and its image. <u> = f h^3 / (12 mu H), so K = h^3 / (12 H) along
    the layer, exactly for quadratic velocities, and no flow across it."""
    fields = layered_fields(kind, (2, 2, 10), porous_below=0.3)
    result = permeability(fields, PermeabilityOptions(yarns="impermeable"))
    h, H = 0.7, 1.0
    exact = h**3 / (12 * H)
    assert result.K[0, 0] == pytest.approx(exact, rel=1e-10)
    assert result.K[1, 1] == pytest.approx(exact, rel=1e-10)
    assert abs(result.K[2, 2]) < 1e-12 * exact and np.abs(result.K - np.diag(np.diag(result.K))).max() < 1e-12 * exact
    assert result.porosity == pytest.approx(0.7, rel=1e-12)


@pytest.mark.mpi
@pytest.mark.parametrize("kind", ["tet", "hex"])
def test_a_homogeneous_porous_block_has_its_own_rotated_permeability(kind):
    """A cell that is one yarn throughout: u = K f / mu is uniform and the pressure constant, which
    the elements hold exactly; the cell's K is the yarn's tensor at its orientation."""
    a = np.array([1.0, 2.0, 2.0]) / 3.0
    fields = layered_fields(kind, (2, 2, 2), porous_below=2.0, direction=a, vf=0.55)
    result = permeability(fields, PermeabilityOptions(fibre_radius=0.004))
    expected = gebart.tensors(a[None], gebart.axial(0.55, 0.004), gebart.transverse(0.55, 0.004))[0]
    assert np.allclose(result.K, expected, rtol=0, atol=1e-10 * np.abs(expected).max())
    assert result.checks["asymmetry"] < 1e-10 and result.checks["positive_definite"]


def brinkman_channel(k: float, porous: float, free: float) -> float:
    """K_xx of a periodic stack of a porous layer (isotropic k, thickness `porous`) and a free one
    (thickness `free`), mu the same in both. With s across the free layer from its centre and z
    across the porous one from its centre, u_free = C - f s^2 / (2 mu) and u_porous = f k / mu + A
    cosh(z / sqrt k); u and u' continuous at the interfaces give A = f b sqrt(k) / (mu sinh(a / sqrt
    k)), C = f (k + b sqrt(k) coth(a / sqrt k) + b^2 / 2) / mu, a and b the half-thicknesses. The mean
    over the cell is (2 f k a + 2 f b k + 2 b C mu - f b^3 / 3 ... ) / H, below with mu = f = 1. As
    k -> 0 it is Poiseuille's h^3 / (12 H)."""
    a, b = porous / 2, free / 2
    root = np.sqrt(k)
    C = k + b * root / np.tanh(a / root) + b**2 / 2
    return (2 * k * a + 2 * b * k + 2 * b * C - b**3 / 3) / (porous + free)


@pytest.mark.mpi
def test_a_brinkman_layer_beside_a_free_layer_converges_to_its_closed_form():
    """Porous layer 0.4 thick (k = 0.01 mm^2) below a free layer 0.6: K_xx against the closed form
    (brinkman_channel) on 10, 20 and 40 elements across; the error falls at least 8 x per halving
    (P2: third order or better) and is under 1e-4 at 40; across the layers the flow is Darcy's
    through the layer in series with nothing: K_zz = k H / porous."""
    k, porous, free = 0.01, 0.4, 0.6
    exact = brinkman_channel(k, porous, free)
    assert brinkman_channel(1e-16, porous, free) == pytest.approx(free**3 / 12, rel=1e-6)  # Poiseuille's limit
    errors = []
    for n in (10, 20, 40):
        fields = layered_fields("hex", (1, 1, n), porous_below=porous)
        result = permeability(fields, PermeabilityOptions(yarns=k * MM2_TO_M2))
        errors.append(abs(result.K[0, 0] - exact) / exact)
        assert result.K[2, 2] == pytest.approx(k * (porous + free) / porous, rel=1e-9)
    assert errors[1] < errors[0] / 8 and errors[2] < errors[1] / 8, errors
    assert errors[2] < 1e-4, errors


# Flow across a square array of parallel impermeable cylinders at solid fraction 0.6: K / L^2 (L the
# array's spacing) by Sangani & Acrivos' boundary-integral solution (Int. J. Multiphase Flow 8, 1982)
SQUARE_ARRAY_K = 5.671e-4
# the mesh sizes on the cylinder's surface [mm], L = 1 mm: 10k to 43k unknowns
CYLINDER_SIZES = tuple(0.04 / np.sqrt(2) ** k for k in range(4))


@pytest.mark.mpi
def test_flow_across_a_square_array_of_cylinders_is_sangani_and_acrivos():
    """One cylinder of radius L sqrt(0.6 / pi) along z in an L x L x h periodic cell (L = 1 mm, so K
    in mm^2 is K / L^2), the cylinder impermeable (no-slip on its surface), meshed at h = 0.02 mm on
    its surface. The reference is Sangani & Acrivos' K / L^2 = 5.671e-4, a boundary-integral
    solution of this very Stokes problem; Gebart's formula for square arrays, 16 / (9 pi sqrt 2)
    (sqrt(pi / (4 Vf)) - 1)^2.5 r^2 = 6.03e-4, is not: it is a lubrication estimate for the narrow
    gaps (here 0.126 L), exact only as they close, and 6 % high at Vf = 0.6, three times the 2 %
    this test allows (measured 2026-12-07: 5.6826e-4 and 5.6824e-4, 0.20 % high, the faceted
    cylinder's error: test below). A quarter turn maps the array onto itself, so Kxx = Kyy and K_xy
    = 0; the mesh is not symmetric, so they hold only to its error (measured |Kxx - Kyy| = 3.5e-5
    Kxx, |K_xy| = 2e-6 Kxx), well inside that against the reference."""
    fields, _ = cylinder_cell(0.6, 0.02)
    result = permeability(fields, PermeabilityOptions(yarns="impermeable"))
    K = result.K
    assert K[0, 0] == pytest.approx(SQUARE_ARRAY_K, rel=0.02)
    assert K[1, 1] == pytest.approx(SQUARE_ARRAY_K, rel=0.02)
    assert abs(K[0, 0] - K[1, 1]) < 2e-4 * K[0, 0]
    assert np.abs(K - np.diag(np.diag(K))).max() < 1e-5 * K[0, 0]
    assert K[2, 2] > K[0, 0]  # along the cylinders the fluid need not squeeze through the gaps
    # the faceted cylinder is inscribed in the circle: a little less solid than 0.6
    assert 0.4 < result.porosity < 0.4 + 2e-4


@pytest.mark.mpi
def test_flow_across_a_square_array_of_cylinders_converges_at_second_order():
    """The cell of the test above at sizes h = 0.04 mm / sqrt(2)^k, k = 0 to 3 (10k to 43k
    unknowns). The error of K_xx and K_yy against Sangani & Acrivos' 5.671e-4 falls as h^2
    (measured 2026-12-07: K_xx 5.7200, 5.6939, 5.6826, 5.6764e-4, errors 0.86, 0.40, 0.20, 0.096 %,
    rates 2.2, 2.0, 2.2 per step and 2.10 by least squares; K_yy's 2.1, 1.9, 2.2 and 2.04; 6 s
    serially, 15 s under mpirun -n 2): the error of the faceted cylinder, whose inscribed polygon
    misses an area ~ h^2 (the porosity 0.4 + 6.2e-4, 3.0e-4, 1.5e-4, 0.8e-4 halves per step too)
    and so widens the gaps: K is high at every size, and Taylor-Hood's own error in the velocity is
    smaller. Richardson's extrapolation at order 2 from the two finest meshes gives 5.6703e-4,
    0.012 % below the reference."""
    values = []
    for h in CYLINDER_SIZES:
        fields, _ = cylinder_cell(0.6, h)
        values.append(np.diag(permeability(fields, PermeabilityOptions(yarns="impermeable")).K)[:2])
    values = np.array(values)
    errors = values / SQUARE_ARRAY_K - 1
    assert np.all(errors > 0), errors  # the faceted cylinder leaves wider gaps
    rates = np.log(errors[:-1] / errors[1:]) / np.log(np.sqrt(2))
    assert np.all(rates > 1.7), rates
    fitted = [np.polyfit(np.log(CYLINDER_SIZES), np.log(e), 1)[0] for e in errors.T]
    assert np.allclose(fitted, 2.1, atol=0.3), fitted
    assert np.all(errors[-1] < 1.5e-3), errors
    extrapolated = values[-1] + (values[-1] - values[-2]) / (2.0 - 1.0)  # (h_k / h_k+1)^2 = 2
    assert np.allclose(extrapolated, SQUARE_ARRAY_K, rtol=5e-4), extrapolated


@pytest.mark.mpi
def test_permeability_falls_with_the_yarns_permeability_and_is_the_same_on_two_ranks(mpi_tmp_path):
    """K is monotone in the yarns' permeability (more drag, less flow) and bounded below by the
    impermeable yarns'; the whole tensor (permeability.json) is the same on every rank's own serial
    run as on all the ranks together, to 1e-8."""
    results = [permeability(layered_fields("tet", (2, 2, 6), porous_below=0.5, direction=(1.0, 1.0, 0.5)),
                            PermeabilityOptions(yarns=y, fibre_radius=0.005))
               for y in ("impermeable", "gebart", 1e-9)]
    kxx = [r.K[0, 0] for r in results]
    assert kxx[0] < kxx[1] < kxx[2]  # Gebart's yarn at Vf 0.5 and r 5 um: under 1e-9 m^2 in every direction
    serial = permeability(layered_fields("tet", (2, 2, 6), porous_below=0.5, direction=(1.0, 1.0, 0.5),
                                         comm=MPI.COMM_SELF), PermeabilityOptions(fibre_radius=0.005))
    assert np.allclose(results[1].K, serial.K, rtol=0, atol=1e-8 * np.abs(serial.K).max())
    assert results[1].checks["asymmetry"] < 1e-8 and results[1].checks["positive_definite"]
    results[1].write(mpi_tmp_path, MPI.COMM_WORLD)
    MPI.COMM_WORLD.barrier()
    doc = json.loads((mpi_tmp_path / "permeability.json").read_text())
    assert np.allclose(doc["K_m2"], results[1].K * MM2_TO_M2, rtol=1e-15)
    assert doc["checks"]["positive_definite"] and len(doc["principal_m2"]) == 3


def xdmf_fields(path) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """The mesh (points, cells) and every field by name of an XDMF file of DOLFINx, read as
    ParaView reads it: its XML names each grid's datasets in the .h5 beside it."""
    import xml.etree.ElementTree as ET

    import h5py

    items = {}
    for grid in ET.parse(path).getroot().iter("Grid"):
        if grid.get("GridType") == "Uniform":
            for tag in ("Topology", "Geometry", "Attribute"):
                item = grid.find(f"{tag}/DataItem")
                if item is not None:
                    items[grid.get("Name") if tag == "Attribute" else tag] = item.text.strip().split(":", 1)[1]
    with h5py.File(path.with_suffix(".h5"), "r") as h5:
        data = {name: np.asarray(h5[dataset]) for name, dataset in items.items()}
    return data.pop("Geometry"), data.pop("Topology"), data


def p1_mean(points: np.ndarray, cells: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The mean over the cells (tetrahedra, or boxes along the axes) of the field linear (trilinear)
    in each with these values (N, ...) at their vertices: the mean of a cell's vertex values is
    its own mean."""
    x = points[cells]
    if cells.shape[1] == 4:
        volumes = np.abs(np.linalg.det(x[:, 1:] - x[:, :1])) / 6
    else:
        volumes = np.prod(np.ptp(x, axis=1), axis=1)
    return np.tensordot(volumes, values[cells].mean(axis=1), axes=1) / volumes.sum()


def poiseuille(z: np.ndarray, below: float = 0.3, top: float = 1.0) -> np.ndarray:
    """The velocity [mm/s] of plane Poiseuille flow at a gradient of 1 Pa/mm (mu = 1 Pa s) between
    walls at z = below and z = top, 0 below the gap (the impermeable layer)."""
    s = z - below
    return np.where(s > 0, s * (top - below - s) / 2, 0.0)


@pytest.mark.mpi
@pytest.mark.parametrize("kind", ["tet", "hex"])
def test_the_flow_files_hold_each_load_case_for_paraview(kind, mpi_tmp_path):
    """Poiseuille flow between plates (the cell of test_poiseuille_between_plates_is_exact, 7
    elements across the gap h = 0.7): its velocity is quadratic, so Taylor-Hood's is exact, and so
    are the files at their nodes. flow.xdmf (read as ParaView reads it, and by DOLFINx) holds the
    velocity at the vertices: exact there, and linear between them, which is the trapezoidal rule
    across the gap: its mean along x is K_xx (1 - 1 / 7^2) exactly. flow.vtu (pyvista) holds the
    arrays of every load case at every node of the P2 velocity, the closed form there, and its
    quadratic cells interpolate it as the elements do (VTK's probe, at random points: this checks
    their nodes' order). The periodic pressure is 0 along the layer; across it nothing flows, and
    the pressure balances the gradient: p - z is constant in the gap. flow.png is a picture."""
    import matplotlib.image
    import pyvista

    from textile_fenicsx.flow.files import FILES

    fields = layered_fields(kind, (2, 2, 10), porous_below=0.3)
    result = permeability(fields, PermeabilityOptions(yarns="impermeable"))
    result.write(mpi_tmp_path, MPI.COMM_WORLD)
    nodes = dolfinx.fem.functionspace(fields.mesh, ("Lagrange", 2)).dofmap.index_map.size_global
    with dolfinx.io.XDMFFile(MPI.COMM_WORLD, str(mpi_tmp_path / "flow.xdmf"), "r") as f:
        read = f.read_mesh(name="mesh")
    vertices = read.geometry.index_map().size_global
    assert read.topology.index_map(3).size_global == fields.mesh.topology.index_map(3).size_global
    if MPI.COMM_WORLD.rank != 0:
        return
    assert all((mpi_tmp_path / name).is_file() for name in ("permeability.json", *FILES))
    Kxx = result.K[0, 0]
    assert Kxx == pytest.approx(0.7**3 / 12, rel=1e-10)
    points, cells, data = xdmf_fields(mpi_tmp_path / "flow.xdmf")
    assert len(points) == vertices == 3 * 3 * 11
    assert set(data) == {f"{q}_{c}" for q in ("velocity", "pressure") for c in "xyz"}
    for j, case in enumerate("xyz"):
        u = data[f"velocity_{case}"]
        expected = np.zeros_like(u)
        expected[:, j] = poiseuille(points[:, 2]) if case != "z" else 0.0
        assert np.abs(u - expected).max() < 1e-10 * Kxx
    assert np.abs(data["pressure_x"]).max() < 1e-10 and np.abs(data["pressure_y"]).max() < 1e-10
    gap = points[:, 2] > 0.3 - 1e-9  # across the layer nothing flows: the whole pressure is still in the gap
    assert np.ptp(data["pressure_z"][gap, 0] - points[gap, 2]) < 1e-10
    assert p1_mean(points, cells, data["velocity_x"]) == pytest.approx([Kxx * (1 - 1 / 7**2), 0, 0], abs=1e-12)
    assert p1_mean(points, cells, data["velocity_y"])[1] == pytest.approx(Kxx * (1 - 1 / 7**2), rel=1e-10)

    grid = pyvista.read(mpi_tmp_path / "flow.vtu")
    assert grid.n_points == nodes and grid.n_cells == fields.mesh.topology.index_map(3).size_global
    assert set(np.unique(grid.celltypes)) == {pyvista.CellType.QUADRATIC_TETRA if kind == "tet"
                                              else pyvista.CellType.TRIQUADRATIC_HEXAHEDRON}
    assert set(grid.point_data.keys()) == set(data)
    assert grid.point_data["velocity_x"].shape == (nodes, 3) and grid.point_data["pressure_z"].shape == (nodes,)
    z = grid.points[:, 2]
    assert np.array_equal(np.lexsort(grid.points.T), np.arange(nodes))  # by location: the same on any ranks
    assert np.abs(grid.point_data["velocity_x"][:, 0] - poiseuille(z)).max() < 1e-10 * Kxx
    assert np.abs(grid.point_data["velocity_y"][:, 1] - poiseuille(z)).max() < 1e-10 * Kxx
    assert np.abs(grid.point_data["velocity_z"]).max() < 1e-10 * Kxx
    assert np.abs(grid.point_data["pressure_x"]).max() < 1e-10
    assert np.ptp((grid.point_data["pressure_z"] - z)[z > 0.3 - 1e-9]) < 1e-10
    assert np.isin(np.round(z, 9), np.round(np.linspace(0, 1, 21), 9)).all()  # every node: vertices and midpoints
    at = np.random.default_rng(0).uniform(0.01, 0.99, (200, 3))
    probe = pyvista.PolyData(at).sample(grid)
    assert probe.point_data["vtkValidPointMask"].all()
    assert np.abs(probe.point_data["velocity_x"][:, 0] - poiseuille(at[:, 2])).max() < 1e-4 * poiseuille(0.65)

    png = (mpi_tmp_path / "flow.png").read_bytes()
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and len(png) > 20_000
    height, width = matplotlib.image.imread(mpi_tmp_path / "flow.png").shape[:2]
    assert height > 1000 and width > 800


@pytest.mark.serial
def test_a_failed_write_leaves_the_folder_as_it_was(tmp_path, monkeypatch):
    """Permeability.write puts its files into the folder together: where one fails (here the
    picture, as on a full disk) none lands, an earlier permeability.json stays, the error names
    the file as it would have been in the folder, and nothing is left beside it. A write that
    succeeds replaces the earlier results and keeps the folder's other files (the volume mesh's,
    where the permeability is written beside it)."""
    import errno

    from textile_fenicsx.flow.files import FILES
    from textile_fenicsx.plot import flow_figures

    result = permeability(layered_fields("hex", (1, 1, 4), porous_below=0.5, comm=MPI.COMM_SELF),
                          PermeabilityOptions(yarns="impermeable"))
    folder = tmp_path / "vol"
    folder.mkdir()
    (folder / "permeability.json").write_text("earlier")
    (folder / "volume.xdmf").write_text("the mesh")

    def full(vtu, path, *args):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    with monkeypatch.context() as m:
        m.setattr(flow_figures, "flow_cuts", full)
        with pytest.raises(OSError) as failed:
            result.write(folder, MPI.COMM_SELF)
    assert failed.value.filename == str(folder / "flow.png")
    assert sorted(p.name for p in folder.iterdir()) == ["permeability.json", "volume.xdmf"]
    assert (folder / "permeability.json").read_text() == "earlier"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["vol"]
    result.write(folder, MPI.COMM_SELF)
    assert sorted(p.name for p in folder.iterdir()) == sorted(["permeability.json", "volume.xdmf", *FILES])
    assert json.loads((folder / "permeability.json").read_text())["K_mm2"] == result.K.tolist()


def test_bad_options_are_refused():
    for bad in ({"yarns": "leaky"}, {"yarns": -1.0}, {"yarns": float("nan")}, {"fibre_radius": 0.0},
                {"degree": 1}):
        with pytest.raises(TextileError):
            PermeabilityOptions(**bad)


@pytest.mark.serial
def test_the_permeability_command_on_a_meshed_cross_ply(tmp_path):
    """volume-mesh then permeability, as a user runs them, on the cross-ply of test_volume: K in
    permeability.json is symmetric and positive definite, in-plane Kxx = Kyy (the model's 90-degree
    rotation maps it onto itself), and the impermeable yarns let less through than Gebart's. The
    flow's files are written beside permeability.json: flow.xdmf (+.h5), flow.vtu with the three
    load cases' arrays (pyvista), flow.png. Bad input exits 2 naming the culprit and leaves no
    output; a memory limit too small is refused, and writes nothing into the mesh's own folder."""
    import subprocess

    import pyvista
    from test_volume import cross_ply

    from textile_fenicsx.cli.volume_commands import PERMEABILITY_FILES
    from textile_fenicsx.flow.files import FILES
    from textile_fenicsx.io.config import save_model

    assert PERMEABILITY_FILES == ("permeability.json", *FILES)  # the CLI's names without importing DOLFINx

    model = tmp_path / "cross_ply.json"
    save_model(cross_ply(), model)

    def run(*args):
        return subprocess.run(["textile-fenicsx", *args], capture_output=True, text=True, timeout=600)

    assert run("volume-mesh", str(model), "--kind", "voxel", "--size", "0.4", "--yarn-vf", "0.6", "--out",
               str(tmp_path / "vol")).returncode == 0
    mesh = str(tmp_path / "vol" / "volume.xdmf")
    r = run("permeability", mesh, "--fibre-radius", "0.0035", "--out", str(tmp_path / "k"))
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "k" / "permeability.json").read_text())
    K = np.array(doc["K_m2"])
    assert doc["checks"]["asymmetry"] < 1e-8 and doc["checks"]["positive_definite"]
    assert K[0, 0] == pytest.approx(K[1, 1], rel=1e-6)
    assert r.stdout.startswith("Kxx ") and "m^2" in r.stdout
    assert sorted(p.name for p in (tmp_path / "k").iterdir()) == sorted(PERMEABILITY_FILES)
    grid = pyvista.read(tmp_path / "k" / "flow.vtu")
    assert set(grid.point_data.keys()) == {f"{q}_{c}" for q in ("velocity", "pressure") for c in "xyz"}
    speed = np.linalg.norm(grid.point_data["velocity_x"], axis=1)
    assert speed.max() > 0 and grid.n_cells == 200  # 10 x 10 x 2 voxels
    assert (tmp_path / "k" / "flow.png").read_bytes().startswith(b"\x89PNG\r\n\x1a\n")
    r = run("permeability", mesh, "--yarn-permeability", "impermeable", "--solver", "iterative", "--out",
            str(tmp_path / "solid"))
    assert r.returncode == 0, r.stderr
    assert " iterations, " in r.stdout  # FGMRES's, in the summary
    solid = np.array(json.loads((tmp_path / "solid" / "permeability.json").read_text())["K_m2"])
    assert np.all(np.diag(solid) < np.diag(K))
    for args, words in ((["--yarn-permeability", "leaky"], "gebart, impermeable or a permeability"),
                        (["--yarn-permeability=-1e-9"], "positive number of m^2"),
                        (["--solver", "cg"], "invalid choice: 'cg'"),
                        (["--fibre-radius", "0"], "fibre radius must be a positive length"),
                        (["--memory-limit", "0.001"], "need about")):
        r = run("permeability", mesh, *args, "--out", str(tmp_path / "bad"))
        assert r.returncode == 2 and words in r.stderr, r.stderr
        assert not (tmp_path / "bad").exists()
    before = sorted(p.name for p in (tmp_path / "vol").iterdir())
    r = run("permeability", mesh, "--memory-limit", "0.001", "--out", str(tmp_path / "vol"))
    assert r.returncode == 2 and sorted(p.name for p in (tmp_path / "vol").iterdir()) == before
    r = run("permeability", str(tmp_path / "missing.xdmf"), "--out", str(tmp_path / "bad"))
    assert r.returncode == 2 and "missing.xdmf" in r.stderr and not (tmp_path / "bad").exists()


@pytest.mark.mpi
@pytest.mark.parametrize("kind", ["tet", "hex"])
def test_the_iterative_solver_agrees_with_the_direct_one(kind):
    """FGMRES with the block preconditioner (problem.ITERATIVE) stops at a residual 1e-6 of the
    load's: K within 1e-5 of its largest entry of MUMPS' LU, on a Gebart yarn (drag contrast 1e6
    with the pores: mu / K_yarn ~ 1e6 mm^-2 against mu / h^2 ~ 10) beside a free layer, in a few
    tens of iterations a load case."""
    fields = layered_fields(kind, (3, 3, 8), porous_below=0.5, direction=(1.0, 1.0, 0.5))
    direct = permeability(fields, PermeabilityOptions(fibre_radius=0.005, solver="direct"))
    iterative = permeability(fields, PermeabilityOptions(fibre_radius=0.005, solver="iterative"))
    scale = np.abs(direct.K).max()
    assert np.allclose(iterative.K, direct.K, rtol=0, atol=1e-5 * scale)
    assert direct.options["iterations"] == [1, 1, 1] and "MUMPS" in direct.options["solver"]
    assert all(0 < n < 100 for n in iterative.options["iterations"]), iterative.options["iterations"]
    assert "p-multigrid" in iterative.options["solver"]
    with pytest.raises(TextileError, match="flow solver must be one of"):
        PermeabilityOptions(solver="cg")


def flow_problem(fields: VolumeFields, yarns, options: dict) -> FlowCellProblem:
    """The flow cell problem of permeability() on `fields` with the PETSc options given."""
    K_yarn, yarn = yarn_permeability(fields, PermeabilityOptions(yarns=yarns, fibre_radius=0.005))
    T = dolfinx.fem.functionspace(fields.mesh, ("DG", 0, (3, 3)))
    K_inv = dolfinx.fem.Function(T)
    porous = yarn if yarns != "impermeable" else np.zeros_like(yarn)
    inverse = np.zeros_like(K_yarn)
    inverse[porous] = np.linalg.inv(K_yarn[porous])
    K_inv.x.array.reshape(-1, 9)[T.dofmap.list[:, 0]] = inverse.reshape(-1, 9)
    return FlowCellProblem(K_inv, bounding_box(fields.mesh), solid=yarn if yarns == "impermeable" else None,
                           options=options)


@pytest.mark.mpi
@pytest.mark.parametrize("kind", ["tet", "hex"])
@pytest.mark.parametrize("yarns", ["gebart", "impermeable"])
def test_the_velocity_p_multigrid_coarse_level_is_galerkin(kind, yarns):
    """The velocity block's p-multigrid (problem.ITERATIVE, flow/pmultigrid.py): the P1 velocity's
    own matrix is P^T A_uu P, P the exact prolongation into the periodic, reduced velocity block,
    but for its held rows (slaves, and the nodes of solid cells), which are the identity's; K by it
    and by BoomerAMG on P2 itself (ITERATIVE_AMG) is MUMPS' to 1e-5, with the layer solid or a
    Gebart yarn."""
    fields = layered_fields(kind, (3, 3, 8), porous_below=0.5 if yarns == "gebart" else 0.3,
                            direction=(1.0, 1.0, 0.5))
    problem = flow_problem(fields, yarns, ITERATIVE)
    try:
        P, A1 = problem.velocity_levels
        velocity = PETSc.IS().createGeneral(problem.reduction.fields[0].astype(PETSc.IntType), comm=problem.comm)
        Auu = problem.A.createSubMatrix(velocity, velocity)
        galerkin = Auu.PtAP(P)
        difference = A1.copy()
        difference.axpy(-1.0, galerkin, PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        first = difference.getOwnershipRange()[0]
        held = first + np.flatnonzero(np.abs(difference.getDiagonal().getArray() - 1.0) < 0.5)
        assert problem.comm.allreduce(len(held)) > (0 if yarns == "gebart" else 100)
        difference.zeroRows(held.astype(PETSc.IntType), 0.0)
        assert difference.norm() < 1e-12 * A1.norm(), (difference.norm(), A1.norm())
        for obj in (velocity, Auu, galerkin, difference):
            obj.destroy()
        K = {}
        for name, options in (("pmg", ITERATIVE), ("amg", ITERATIVE_AMG), ("direct", DIRECT)):
            solver = problem if name == "pmg" else flow_problem(fields, yarns, options)
            try:
                K[name] = np.array([solver.mean_velocity(w) for w in solver.solve(np.eye(3))]).T
                assert name == "direct" or all(0 < n < 100 for n in solver.iterations), solver.iterations
            finally:
                if solver is not problem:
                    solver.destroy()
    finally:
        problem.destroy()
    scale = np.abs(K["direct"]).max()
    assert np.allclose(K["pmg"], K["direct"], rtol=0, atol=1e-5 * scale)
    assert np.allclose(K["amg"], K["direct"], rtol=0, atol=1e-5 * scale)
