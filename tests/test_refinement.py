"""The discretisation error's estimate (volume/refinement.py, issue 72): Richardson's extrapolation
and Roache's grid convergence index on manufactured sequences, the refinement loop, and the estimate
of homogenised properties on voxel meshes of a model."""

import json
import subprocess

import numpy as np
import pytest
from test_volume import cross_ply, saved_cross_ply

from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.volume.refinement import RATIO, SAFETY, Level, converge, grid_convergence
from textile_fenicsx.volume.voxel_sizes import SCATTER


def manufactured(h: float, p: float = 1.0) -> dict[str, float]:
    # f(h) = f0 + c h^p: f0 = 100 and 2 (c = 30 and -1): the converged values are 100 and 2
    return {"a": 100 + 30 * h**p, "b": 2 - h**p}


def elements(h: float) -> float:
    return 1000 / h**3  # a 3D mesh of element size h: its ratio of sizes is its count's cube root


@pytest.mark.serial
def test_two_meshes_of_an_order_one_sequence_extrapolate_exactly():
    # with the assumed order 1 right, Richardson's value is f0 exactly, and the GCI is 3 x |f1 - f0|
    h = (0.3, 0.2)
    est = grid_convergence([manufactured(x) for x in h], [elements(x) for x in h])
    assert est.extrapolated["a"] == pytest.approx(100, rel=1e-12) and est.extrapolated["b"] == pytest.approx(2)
    assert est.errors["a"] == pytest.approx(SAFETY[2] * 30 * 0.2, rel=1e-9), "Fs 3 times the true error"
    assert est.relative()["b"] == pytest.approx(3 * 0.2 / 1.8, rel=1e-9) and not est.observed["a"]
    with pytest.raises(ValueError, match="finer one after the other"):
        grid_convergence([manufactured(x) for x in h[::-1]], [elements(x) for x in h[::-1]])


@pytest.mark.serial
@pytest.mark.parametrize("p", [0.7, 1.0, 1.7])
def test_three_meshes_observe_the_order(p):
    # three meshes of unequal ratios (0.4, 0.3, 0.2: 4/3 then 3/2) recover p by Celik et al.'s fixed
    # point, extrapolate to f0 exactly, and take Roache's Fs 1.25
    h = (0.4, 0.3, 0.2)
    est = grid_convergence([manufactured(x, p) for x in h], [elements(x) for x in h])
    assert est.orders["a"] == pytest.approx(p, rel=1e-8) and est.observed["a"], "the order observed"
    assert est.extrapolated["a"] == pytest.approx(100, rel=1e-9), "Richardson with the order observed is exact"
    assert est.errors["a"] == pytest.approx(SAFETY[3] * 30 * 0.2**p, rel=1e-7)


@pytest.mark.serial
def test_an_oscillating_sequence_falls_back_to_the_assumed_order():
    # differences that change sign give no order: the assumed one, with Fs 3
    values = [{"a": 10.0}, {"a": 11.0}, {"a": 10.5}]
    est = grid_convergence(values, [elements(x) for x in (0.4, 0.3, 0.2)])
    assert not est.observed["a"] and est.orders["a"] == 1.0
    assert est.errors["a"] == pytest.approx(3 * 0.5 / (1.5 - 1), rel=1e-9), "Fs |f1 - f2| / (r - 1), r = 1.5"


@pytest.mark.serial
def test_converge_refines_until_the_accuracy_is_met():
    # f = (100 + 30 h, 2 - h), h = 0.3 x scale, the worst relative error b's: with two meshes
    # (scales 1.5 and 1) its GCI is 3 h / (2 - h) = 53 %; with three, order 1 observed exactly and Fs
    # 1.25, 1.25 h / (2 - h): 13.9 % at scale 1 / 1.5, 8.9 % at 1 / 1.5^2, where 10 % is met
    scales = []

    def solve_at(scale):
        scales.append(scale)
        h = 0.3 * scale
        return Level(h, manufactured(h), int(round(elements(h))), int(round(3 * elements(h))), scale)

    finest, est = converge(solve_at, accuracy=0.10)
    assert scales == pytest.approx([RATIO, 1, 1 / RATIO, 1 / RATIO**2])
    h = 0.3 / RATIO**2
    assert est.met() and est.worst() == ("b", pytest.approx(1.25 * h / (2 - h), rel=1e-4))
    assert finest == pytest.approx(h) and est.observed["a"] and est.stopped is None
    scales.clear()
    finest, est = converge(solve_at)  # no accuracy: the mesh asked and one coarser
    assert scales == [RATIO, 1] and est.met() and est.accuracy is None

    def runs_out(scale):  # the third mesh does not fit
        if scale < 1:
            raise TextileError("homogenising with 9e6 elastic unknowns would need about 60 GB")
        return solve_at(scale)

    finest, est = converge(runs_out, accuracy=0.10)  # the finest result kept, with why it stopped
    assert finest == pytest.approx(0.3) and not est.met() and "x 0.667 failed: homogenising" in est.stopped
    assert est.worst()[0] == "b" and est.worst()[1] == pytest.approx(3 * 0.3 / (2 - 0.3), rel=1e-4)

    def fails_early(scale):
        raise TextileError("no mesh")

    with pytest.raises(TextileError, match="no mesh"):
        converge(fails_early, accuracy=0.10)
    with pytest.raises(TextileError, match="between 0 and 1"):
        converge(solve_at, accuracy=5)
    with pytest.raises(TextileError, match="finer than these meshes can show"):
        converge(solve_at, accuracy=0.01, floor=0.015)
    finest, est = converge(solve_at, floor=0.05)  # a floor lifts the errors below it, not those above
    assert est.errors["a"] == pytest.approx(max(0.05 * 109, 3 * 4.5 / (1.5 - 1)), rel=1e-3)
    assert est.errors["b"] == pytest.approx(3 * 0.15 / 0.5, rel=1e-3) and est.floor == 0.05


@pytest.mark.mpi
def test_homogenising_a_model_estimates_its_error(comm):
    # the cross-ply on voxels of 0.2 x 0.2 x 0.05 mm and 1.5 x coarser, first order: the estimate is the same on
    # every rank, its extrapolated value is f1 + (f1 - f2) / (r - 1) from the meshes reported, and the
    # value on a mesh 1.5 x finer lies within value +- error (the bound the estimate claims)
    import textile_fenicsx as tfx
    from textile_fenicsx.volume.stage import VolumeOptions

    r = tfx.homogenise_model(cross_ply(), VolumeOptions("voxel", (0.2, 0.2, 0.05), yarn_vf=0.6), comm=comm,
                             degree=1, conduction=False)
    est = r.error
    assert [m["scale"] for m in est["meshes"]] == [RATIO, 1] and est["accuracy_met"]
    assert comm.allgather(est["quantities"]["Ex"]["error"]) == [est["quantities"]["Ex"]["error"]] * comm.size
    m = est["meshes"]
    ratio = (m[1]["elements"] / m[0]["elements"]) ** (1 / 3)
    assert 1.3 < ratio < 1.7, "the coarse mesh's sizes are about 1.5 x"
    for k in ("Ex", "Ez", "Gxy"):
        q = est["quantities"][k]
        assert q["value"] == pytest.approx(r.constants[k], rel=1e-12), "the finest mesh's value"
        coarse = q["value"] - (q["extrapolated"] - q["value"]) * (ratio - 1)
        gci = 3 * abs(q["value"] - coarse) / (ratio - 1)
        assert q["error"] == pytest.approx(max(gci, SCATTER * abs(q["value"])), rel=1e-9), "GCI, or the floor"
    finer = tfx.homogenise(tfx.volume_mesh(cross_ply(), "voxel", (0.2, 0.2, 0.05), comm=comm, yarn_vf=0.6,
                                           scale=1 / RATIO), comm=comm, degree=1, conduction=False)
    for k in ("Ex", "Ez", "Gxy"):
        q = est["quantities"][k]
        assert abs(finer.constants[k] - q["value"]) <= q["error"], (k, finer.constants[k], q)


@pytest.mark.serial
def test_a_tet_mesh_gets_no_estimate():
    # a tet mesh's size does not coarsen it (the gaps and curvature set its elements): refused, before
    # any mesh, saying why
    import textile_fenicsx as tfx
    from textile_fenicsx.volume.stage import VolumeOptions

    with pytest.raises(TextileError, match=r"needs voxel meshes.*1.5 x the size gave 0.98 x the tets"):
        tfx.homogenise_model(cross_ply(), VolumeOptions("tet", 0.5, yarn_vf=0.6))


@pytest.mark.serial
def test_homogenise_command_on_a_model_writes_the_estimate(tmp_path):
    # `homogenise MODEL --size ...`: stiffness.json's error_estimate; an accuracy too fine
    # for the meshes allowed exits 1 with stiffness.json holding the finest and its estimate; the
    # options that need a model are refused on a mesh (exit 2, no output)
    model = saved_cross_ply(tmp_path)

    def run(*args):
        return subprocess.run(["textile-fenicsx", "homogenise", *args, "--degree", "1", "--no-conduction",
                               "--yarn-vf", "0.6"], capture_output=True, text=True, timeout=600)

    r = run(str(model), "--size", "0.4", "0.4", "0.1", "--out", str(tmp_path / "h"))
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads((tmp_path / "h" / "stiffness.json").read_text())
    est = doc["error_estimate"]
    assert len(est["meshes"]) == 2 and est["quantities"]["Ex"]["value"] == doc["engineering_constants"]["Ex"]
    assert "estimated error at most" in r.stdout
    # 2 %: the cross-ply's coarse voxels are 10-20 % off, and five meshes do not reach it
    r = run(str(model), "--size", "0.4", "0.4", "0.1", "--accuracy", "2", "--out", str(tmp_path / "fine"))
    assert r.returncode == 1 and "accuracy 2 % not reached" in r.stderr and "5 meshes" in r.stderr, r.stderr[-2000:]
    doc = json.loads((tmp_path / "fine" / "stiffness.json").read_text())
    assert len(doc["error_estimate"]["meshes"]) == 5 and not doc["error_estimate"]["accuracy_met"]
    # 1 %: below what voxels can show (their scatter, SCATTER), refused before any work
    r = run(str(model), "--accuracy", "1", "--out", str(tmp_path / "bad"))
    assert r.returncode == 2 and "finer than these meshes can show" in r.stderr, r.stderr[-2000:]
    r = run(str(tmp_path / "h" / "stiffness.json"), "--out", str(tmp_path / "bad"))
    assert r.returncode == 2
    r = run(str(tmp_path / "vol.xdmf"), "--accuracy", "1", "--out", str(tmp_path / "bad"))
    assert r.returncode == 2 and "--accuracy, --yarn-vf need a model" in r.stderr, r.stderr[-2000:]
    assert not (tmp_path / "bad").exists()
    assert np.isfinite(est["quantities"]["Gxy"]["relative_error"])
    # `permeability MODEL`: the same, permeability.json's error_estimate on Kxx, Kyy, Kzz
    r = subprocess.run(["textile-fenicsx", "permeability", str(model), "--size", "0.4", "0.4", "0.1", "--yarn-vf",
                        "0.6", "--fibre-radius", "0.0035", "--out", str(tmp_path / "k")], capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads((tmp_path / "k" / "permeability.json").read_text())
    assert set(doc["error_estimate"]["quantities"]) == {"Kxx", "Kyy", "Kzz"} and "estimated error" in r.stdout


# The converged values of TexGen's plain weave and 4-harness satin (E-glass in epoxy, yarn Vf 0.65, at
# the voxels' z-range), with their uncertainty [MPa]: docs/volume.md, "Voxel sizes" (first-order
# values on grids 2-3 x finer than the default, less their own discretisation error)
CONVERGED = {"plain": {"Ex": (21729, 56), "Ez": (9380, 4), "Gxy": (3815, 14)},
             "satin4": {"Ex": (23275, 55), "Ez": (9780, 39), "Gxy": (3789, 7)}}


@pytest.mark.mpi
@pytest.mark.slow
@pytest.mark.parametrize("name", ["plain", "satin4"])
def test_the_default_voxels_estimate_brackets_the_converged_value(comm, name):
    # the default voxel mesh and one 1.5 x coarser: each of Ex, Ez, Gxy is within its estimated error
    # of the converged value (give or take that value's own uncertainty). 2 and 6.5 min on 2 ranks.
    import textile_fenicsx as tfx

    r = tfx.homogenise_model(f"reference/models/{name}.tg3", comm=comm, conduction=False)
    for k, (converged, uncertainty) in CONVERGED[name].items():
        q = r.error["quantities"][k]
        assert abs(q["value"] - converged) <= q["error"] + uncertainty, (k, q, converged)
        assert q["error"] >= SCATTER * abs(q["value"]), "at least the voxels' scatter"


@pytest.mark.mpi
def test_the_permeability_of_a_model_estimates_its_error(comm, tmp_path):
    # the cross-ply's permeability on voxels of 0.4 x 0.4 x 0.1 mm and 1.5 x coarser: the diagonal's
    # estimate, Kxx = Kyy on both (the balanced cross-ply's quarter turn) so their estimates agree,
    # each error at least the voxels' floor, the same on every rank; permeability.json carries it
    import textile_fenicsx as tfx
    from textile_fenicsx.volume.stage import VolumeOptions

    k = tfx.permeability_model(cross_ply(), VolumeOptions("voxel", (0.4, 0.4, 0.1), yarn_vf=0.6),
                               fibre_radius=0.0035, comm=comm)
    q = k.error["quantities"]
    assert set(q) == {"Kxx", "Kyy", "Kzz"} and len(k.error["meshes"]) == 2
    assert q["Kxx"]["value"] == pytest.approx(q["Kyy"]["value"], rel=1e-6)
    assert q["Kxx"]["error"] == pytest.approx(q["Kyy"]["error"], rel=1e-4)
    for name, i in (("Kxx", 0), ("Kzz", 2)):
        assert q[name]["value"] == pytest.approx(k.K[i, i], rel=1e-12) and q[name]["value"] > 0
        assert q[name]["error"] >= SCATTER * q[name]["value"] * (1 - 1e-12)
    assert comm.allgather(q["Kzz"]["error"]) == [q["Kzz"]["error"]] * comm.size
    out = tmp_path / "k" if comm.size == 1 else None
    if out is not None:
        doc = json.loads(k.write(out, comm).read_text())
        assert doc["error_estimate"]["quantities"]["Kzz"]["error"] == q["Kzz"]["error"]
