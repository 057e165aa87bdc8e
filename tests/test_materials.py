"""Constituents, Chamis' yarn, material files, Voigt notation (homogenise/materials.py, constants.py)."""

import itertools

import numpy as np
import pytest

from textile_fenicsx.common.errors import FormatError, GeometryError, TextileError
from textile_fenicsx.homogenisation.constants import (
    bond_matrix,
    bounds,
    engineering_constants,
    frames,
    orthotropic_stiffness,
    rotate_stiffness,
)
from textile_fenicsx.homogenisation.materials import (
    PRESETS,
    Isotropic,
    Orthotropic,
    TransverselyIsotropic,
    chamis,
    material,
    read_material,
    stiffness,
    yarn_material,
)
from textile_fenicsx.homogenisation.periodic import Box, check_node_periodicity

PATCH = dict(E1=1111.0, E2=2222.0, E3=3333.0, G12=1212.0, G13=1313.0, G23=2323.0, nu12=0.1212, nu13=0.1313,
             nu23=0.2323)
PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))


def tensor_rotation(Cv, R):
    """Independent of constants.bond_matrix: to the 4th-order tensor, rotate, back (engineering shear:
    C_ijkl = Cv[p(ij), q(kl)])."""
    C4 = np.zeros((3, 3, 3, 3))
    for (p, (i, j)), (q, (k, l)) in itertools.product(enumerate(PAIRS), repeat=2):
        for a, b, c, d in ((i, j, k, l), (j, i, k, l), (i, j, l, k), (j, i, l, k)):
            C4[a, b, c, d] = Cv[p, q]
    C4 = np.einsum("ia,jb,kc,ld,abcd->ijkl", R, R, R, R, C4)
    return np.array([[C4[i, j, k, l] for k, l in PAIRS] for i, j in PAIRS])


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_presets_are_the_cited_values():
    glass, t300, epoxy = PRESETS["e-glass"], PRESETS["t300"], PRESETS["epoxy"]
    assert (glass.E, glass.nu, glass.k) == (80e3, 0.2, 1.3)
    assert (t300.E1, t300.E2, t300.G12, t300.G23, t300.nu12, t300.k1) == (230e3, 15e3, 15e3, 7e3, 0.2, 10.5)
    assert t300.nu23 == pytest.approx(0.0714, abs=1e-4)
    assert (epoxy.E, epoxy.nu) == (3.35e3, 0.35)
    assert all("Soden" in m.source for m in PRESETS.values())
    assert material("T300") is t300 and material("Epoxy") is epoxy


def test_chamis_equations_and_their_limits():
    t300, epoxy = PRESETS["t300"], PRESETS["epoxy"]
    vf, s = 0.6, np.sqrt(0.6)
    Gm = 3350 / 2.7
    y = yarn_material(t300, epoxy, vf)
    assert y.E1 == pytest.approx(0.6 * 230e3 + 0.4 * 3350, rel=1e-14)
    assert y.E2 == pytest.approx(3350 / (1 - s * (1 - 3350 / 15e3)), rel=1e-14)
    assert y.G12 == pytest.approx(Gm / (1 - s * (1 - Gm / 15e3)), rel=1e-14)
    assert y.G23 == pytest.approx(Gm / (1 - s * (1 - Gm / 7e3)), rel=1e-14)
    assert y.nu12 == pytest.approx(0.6 * 0.2 + 0.4 * 0.35, rel=1e-14)
    assert y.k1 == pytest.approx(0.6 * 10.5 + 0.4 * 0.2, rel=1e-14)
    assert y.k2 == pytest.approx((1 - s) * 0.2 + s * 0.2 / (1 - s * (1 - 0.2 / 1.0)), rel=1e-14)
    # no fibre: the matrix; all fibre: the fibre; a fibre of matrix: the matrix at any Vf
    for vf, expected in ((0.0, epoxy), (1.0, t300)):
        got = yarn_material(t300, epoxy, vf)
        np.testing.assert_allclose(stiffness(got), stiffness(expected), rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(got.conductivities(), expected.conductivities(), rtol=1e-12)
    np.testing.assert_allclose(stiffness(yarn_material(epoxy, epoxy, 0.37)), stiffness(epoxy), rtol=1e-12, atol=1e-9)
    with pytest.raises(TextileError, match="fibre volume fraction"):
        chamis(t300, epoxy, [0.5, 1.2])
    with pytest.raises(TextileError, match="isotropic matrix"):
        chamis(t300, t300, 0.5)


def test_engineering_constants_round_trip_and_patch_constants():
    C = orthotropic_stiffness(**PATCH)
    got = engineering_constants(C)
    expected = {"Ex": 1111, "Ey": 2222, "Ez": 3333, "Gxy": 1212, "Gxz": 1313, "Gyz": 2323, "nuxy": 0.1212,
                "nuxz": 0.1313, "nuyz": 0.2323}
    for name, value in expected.items():
        assert got[name] == pytest.approx(value, rel=1e-12), name
    # Voigt order 11 22 33 23 13 12: G23 on the 4th diagonal entry, G13 on the 5th (TexGen #22)
    assert C[3, 3] == pytest.approx(2323) and C[4, 4] == pytest.approx(1313) and C[5, 5] == pytest.approx(1212)


def test_bond_rotation_against_the_tensor_rotation():
    C = orthotropic_stiffness(**PATCH)
    rng = np.random.default_rng(7)
    for _ in range(5):
        R = rotation(rng.normal(size=3), rng.uniform(0, np.pi))
        np.testing.assert_allclose(rotate_stiffness(C, R), tensor_rotation(C, R), rtol=1e-12, atol=1e-9)
        assert np.allclose(bond_matrix(R) @ bond_matrix(R.T), np.eye(6))
    # 90 degrees about z swaps x and y
    Cz = rotate_stiffness(C, rotation([0, 0, 1], np.pi / 2))
    assert Cz[0, 0] == pytest.approx(C[1, 1]) and Cz[3, 3] == pytest.approx(C[4, 4])
    iso = stiffness(PRESETS["epoxy"])
    np.testing.assert_allclose(rotate_stiffness(iso, rotation([1, 2, 3], 0.7)), iso, atol=1e-9)


def test_frames():
    assert np.allclose(frames(np.array([1.0, 0, 0])), np.eye(3))
    for a in ([0, 0, 2.0], [0.3, -0.4, 0.5], [0, 1.0, 0]):
        Q = frames(np.array(a))
        assert np.allclose(Q.T @ Q, np.eye(3)) and np.linalg.det(Q) == pytest.approx(1)
        assert np.allclose(Q[:, 0], np.array(a) / np.linalg.norm(a))


def test_bounds_order_two_phases():
    C1, C2 = stiffness(PRESETS["epoxy"]), stiffness(yarn_material(PRESETS["t300"], PRESETS["epoxy"], 0.6))
    voigt, reuss = bounds(np.array([C1, C2, C2]), np.array([2.0, 0.5, 0.5]))
    np.testing.assert_allclose(voigt, (2 * C1 + C2) / 3)
    assert np.linalg.eigvalsh(voigt - reuss).min() > 0


def write(tmp_path, text, name="m.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_material_files(tmp_path):
    iso = read_material(write(tmp_path, 'symmetry = "isotropic"\nE = 3000\nnu = 0.3\nk = 0.25\n'))
    assert iso == Isotropic("m", 3000.0, 0.3, 0.25, source=str(tmp_path / "m.toml"))
    ti = read_material(write(tmp_path, 'name = "fib"\nsymmetry = "transversely_isotropic"\nE1 = 2e5\nE2 = 1e4\n'
                             'G12 = 8e3\nnu12 = 0.25\nnu23 = 0.25\n'))
    assert isinstance(ti, TransverselyIsotropic) and ti.G23 == pytest.approx(4e3) and ti.k1 is None
    text = 'symmetry = "orthotropic"\n' + "".join(f"{k} = {v}\n" for k, v in PATCH.items())
    ortho = material(write(tmp_path, text))
    assert isinstance(ortho, Orthotropic) and ortho.G13 == 1313 and ortho.G23 == 2323


@pytest.mark.parametrize("text, error, culprit", [
    ('symmetry = "isotropic"\nE = 3000\n', FormatError, "needs nu"),
    ('symmetry = "isotropic"\nE = 3000\nnu = 0.3\nG = 1\n', FormatError, "unknown key.*G"),
    ('symmetry = "cubic"\nE = 3000\nnu = 0.3\n', FormatError, "symmetry"),
    ('symmetry = "isotropic"\nE = "stiff"\nnu = 0.3\n', FormatError, "E must be a number"),
    ('symmetry = "isotropic"\nE = 3000\nnu = 0.3\n[oops\n', FormatError, "not valid TOML"),
    ('symmetry = "transversely_isotropic"\nE1 = 2e5\nE2 = 1e4\nG12 = 8e3\nnu12 = 0.25\n', FormatError, "G23"),
    ('symmetry = "isotropic"\nE = -3000\nnu = 0.3\n', TextileError, "E must be > 0"),
    ('symmetry = "isotropic"\nE = 3000\nnu = 0.6\n', TextileError, "positive-definite"),
])
def test_malformed_material_files_name_the_culprit(tmp_path, text, error, culprit):
    path = write(tmp_path, text, "bad.toml")
    with pytest.raises(error, match=culprit) as info:
        read_material(path)
    assert "bad" in str(info.value)


def test_unknown_material_names_the_presets(tmp_path):
    with pytest.raises(TextileError, match="unknown material 'kevlar'.*e-glass, t300, epoxy"):
        material("kevlar")
    with pytest.raises(FormatError, match="missing.toml"):
        material(tmp_path / "missing.toml")


def grid(n=(3, 4, 2), L=(2.0, 3.0, 1.0)):
    axes = [np.linspace(0, L[i], n[i] + 1) for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def test_node_periodicity_checker():
    box = Box((0.0, 0.0, 0.0), (2.0, 3.0, 1.0), 1e-9)
    points = grid()
    check_node_periodicity(points, box)
    moved = points.copy()
    k = np.flatnonzero((moved[:, 0] == 2.0) & (moved[:, 1] == 1.5) & (moved[:, 2] == 0.5))[0]
    moved[k, 1] += 1e-6
    # the + face's node that moved has no image on the - face
    with pytest.raises(GeometryError, match=r"not periodic: on the x faces 1 of 15 node\(s\) of the \+ face .*"
                                            r"e\.g\. \(2, 1\.500001, 0\.5\)"):
        check_node_periodicity(moved, box)
    corner = np.flatnonzero(np.all(points == 0.0, axis=1))[0]
    with pytest.raises(GeometryError, match="not periodic"):
        check_node_periodicity(np.delete(points, corner, axis=0), box)
    with pytest.raises(GeometryError, match="outside the periodic box"):
        check_node_periodicity(np.vstack([points, [[2.5, 0.0, 0.0]]]), box)
