"""The flow stage (textile_fenicsx/flow): the permeability of a periodic cell by Stokes-Brinkman cell
problems, checked against closed forms: Poiseuille flow between plates (exact for Taylor-Hood), a
Brinkman layer beside a free one, a homogeneous porous block at any orientation, Gebart's laws."""

import json

import numpy as np
import pytest
from mpi4py import MPI

import dolfinx
from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.flow import gebart
from textile_fenicsx.flow.effective import MM2_TO_M2, PermeabilityOptions, permeability
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


def test_bad_options_are_refused():
    for bad in ({"yarns": "leaky"}, {"yarns": -1.0}, {"yarns": float("nan")}, {"fibre_radius": 0.0},
                {"degree": 1}):
        with pytest.raises(TextileError):
            PermeabilityOptions(**bad)


@pytest.mark.serial
def test_the_permeability_command_on_a_meshed_cross_ply(tmp_path):
    """volume-mesh then permeability, as a user runs them, on the cross-ply of test_volume: K in
    permeability.json is symmetric and positive definite, in-plane Kxx = Kyy (the model's 90-degree
    rotation maps it onto itself), and the impermeable yarns let less through than Gebart's. Bad
    input exits 2 naming the culprit and leaves no output; a memory limit too small is refused."""
    import subprocess

    from test_volume import cross_ply

    from textile_fenicsx.io.config import save_model

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
    r = run("permeability", mesh, "--yarn-permeability", "impermeable", "--out", str(tmp_path / "solid"))
    assert r.returncode == 0, r.stderr
    solid = np.array(json.loads((tmp_path / "solid" / "permeability.json").read_text())["K_m2"])
    assert np.all(np.diag(solid) < np.diag(K))
    for args, words in ((["--yarn-permeability", "leaky"], "gebart, impermeable or a permeability"),
                        (["--yarn-permeability=-1e-9"], "positive number of m^2"),
                        (["--fibre-radius", "0"], "fibre radius must be a positive length"),
                        (["--memory-limit", "0.001"], "need about")):
        r = run("permeability", mesh, *args, "--out", str(tmp_path / "bad"))
        assert r.returncode == 2 and words in r.stderr, r.stderr
        assert not (tmp_path / "bad").exists()
    r = run("permeability", str(tmp_path / "missing.xdmf"), "--out", str(tmp_path / "bad"))
    assert r.returncode == 2 and "missing.xdmf" in r.stderr and not (tmp_path / "bad").exists()
