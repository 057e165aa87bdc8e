"""Volume meshes of the unit cell: the voxel mesher, the files and their reading back (1 and 2 ranks)."""

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from conftest import gmsh_groups
from textile_fenicsx.common.errors import FormatError, TextileError
from textile_fenicsx.io.config import load_model, textile_from_dict
from textile_fenicsx.volume.box import Box, periodic_mismatch
from textile_fenicsx.volume.stage import VolumeOptions, mesh_cell, volume_mesh


def cross_ply(gap: float = 0.1, fibres: dict | None = None):
    """Two layers of straight elliptical yarns (1.6 x 0.3 mm, 2 mm apart) crossing at 90 degrees, `gap`
    apart through the thickness: no overlap, and each yarn's volume in the cell is pi/4 1.6 0.3 x 4 mm."""
    h = 0.15 + gap / 2
    yarns = [{"name": f"warp {k}", "nodes": [[0, y, h], [4, y, h]], "interpolation": "linear",
              "repeats": [[4, 0, 0], [0, 4, 0]], "section": {"type": "ellipse", "width": 1.6, "height": 0.3}}
             for k, y in enumerate((1.0, 3.0))]
    yarns += [{"name": f"weft {k}", "nodes": [[x, 0, -h], [x, 4, -h]], "interpolation": "linear",
               "repeats": [[4, 0, 0], [0, 4, 0]], "section": {"type": "ellipse", "width": 1.6, "height": 0.3}}
              for k, x in enumerate((1.0, 3.0))]
    d = {"name": "cross_ply", "cell": {"lx": 4, "ly": 4}, "yarns": yarns,
         "resolution": {"spacing": 0.1, "section_points": 256}}
    if fibres:
        d["fibres"] = fibres
    return textile_from_dict(d)


def saved_cross_ply(folder: Path) -> Path:
    """The cross-ply saved as a model file in `folder`."""
    from textile_fenicsx.io.config import save_model

    model = folder / "cross_ply.json"
    save_model(cross_ply(), model)
    return model


def run(*args, timeout: float = 600):
    """The command line, as a user runs it."""
    return subprocess.run(["textile-fenicsx", *args], capture_output=True, text=True, timeout=timeout)


def test_voxel_yarn_volume_converges():
    # the staircase's error oscillates with the grid's phase against the yarns (+6.1 % at 0.1 mm,
    # -1.3 % at 0.04) and shrinks: 3.4 % at 0.05 mm, 0.8 % at 0.025 mm
    t = cross_ply()
    exact = np.pi / 4 * 1.6 * 0.3 * 4
    errors = []
    for size in (0.05, 0.025):
        vm = volume_mesh(t, VolumeOptions("voxel", size, yarn_vf=0.6), MPI.COMM_SELF)
        errors.append(max(abs(y["meshed_volume"] / exact - 1) for y in vm.report["yarns"]))
        # each yarn's model volume (rays) is the ellipse's to the sampling error
        assert all(y["model_volume"] == pytest.approx(exact, rel=2e-3) for y in vm.report["yarns"])
    assert errors[1] < 0.03 and errors[1] < errors[0] / 2


@pytest.mark.mpi
def test_voxel_mesh_is_periodic_with_its_fields(comm):
    t = cross_ply()
    exact = np.pi / 4 * 1.6 * 0.3 * 4
    cell = mesh_cell(t, VolumeOptions("voxel", 0.1, yarn_vf=0.6), comm)
    r = cell.report
    assert r["periodicity"]["periodic"] and r["overlap"]["voxels"] == 0
    assert r["box"]["lo"][2] == pytest.approx(-0.35, abs=2e-3) and r["box"]["hi"][2] == pytest.approx(0.35, abs=2e-3)
    assert r["vf"] == pytest.approx(0.6 * 4 * exact / (16 * 0.7), rel=0.07)  # the voxels' volume: +6.1 %
    if comm.rank == 0:
        vm = cell.mesh
        warp = np.isin(vm.phase, (1, 2))
        weft = np.isin(vm.phase, (3, 4))
        assert np.allclose(np.abs(vm.direction[warp]), [1, 0, 0]) and np.allclose(np.abs(vm.direction[weft]), [0, 1, 0])
        assert np.all(vm.yarn_vf[vm.phase > 0] == 0.6) and np.all(vm.yarn_vf[vm.phase == 0] == 0)
        assert np.all(np.linalg.norm(vm.direction[vm.phase == 0], axis=1) == 0)


@pytest.mark.mpi
def test_volume_files_read_back_with_tags_and_fields(comm, mpi_tmp_path):
    import ufl

    import dolfinx
    from textile_fenicsx.volume.files import read_volume

    t = cross_ply(fibres={"linear_density": 600, "density": 2.55})
    cell = mesh_cell(t, VolumeOptions("voxel", 0.2), comm)
    cell.write(mpi_tmp_path / "vol")
    back = read_volume(mpi_tmp_path / "vol" / "volume.xdmf", comm)

    def integrals(f):
        dx = ufl.Measure("dx", domain=f.mesh, subdomain_data=f.phase)
        one = [dolfinx.fem.form(1.0 * dx(p)) for p in range(5)]
        a = dolfinx.fem.form(ufl.as_vector((1.0, 2.0, 3.0))[0] * abs(f.direction[0]) * dx
                             + abs(f.direction[1]) * dx + f.yarn_vf * dx)
        return [comm.allreduce(dolfinx.fem.assemble_scalar(x), op=MPI.SUM) for x in one + [a]]

    assert np.allclose(integrals(back), integrals(cell.fields), rtol=1e-12)
    if comm.rank == 0:
        names = sorted(p.name for p in (mpi_tmp_path / "vol").iterdir())
        assert names == ["mesh_report.json", "volume.h5", "volume.inp", "volume.msh", "volume.vtu", "volume.xdmf"]
        import meshio

        m = meshio.read(mpi_tmp_path / "vol" / "volume.vtu")
        assert len(m.cells[0].data) == cell.report["elements"]
        # gmsh opens volume.msh with each phase a named group holding that phase's voxels, and its own
        # measure of their volume is the mesh's (no voxel lost, repeated or turned over)
        vm = cell.mesh
        groups = gmsh_groups(mpi_tmp_path / "vol" / "volume.msh")
        names = ["matrix", *vm.yarn_names]
        assert set(groups) == set(names)
        for p, name in enumerate(names):
            assert groups[name][0] == np.count_nonzero(vm.phase == p)
            assert groups[name][1] == pytest.approx(vm.phase_volumes()[p], rel=1e-12)
        back = meshio.read(mpi_tmp_path / "vol" / "volume.msh")  # meshio reads the phases back too (by block)
        assert np.array_equal(np.bincount(np.concatenate(back.cell_data["gmsh:physical"])), np.bincount(vm.phase + 1))
        inp = (mpi_tmp_path / "vol" / "volume.inp").read_text()
        assert inp.count("*Elset") == 5 and "*Orientation, name=FIBRE_AXES" in inp
        vf = 600 / 2550 / (np.pi / 4 * 1.6 * 0.3)  # the fibre data's intra-yarn fraction
        report = json.loads((mpi_tmp_path / "vol" / "mesh_report.json").read_text())
        cell_volume = np.prod(np.subtract(report["box"]["hi"], report["box"]["lo"]))
        assert report["vf"] == pytest.approx(vf * sum(y["meshed_volume"] for y in report["yarns"]) / cell_volume,
                                             rel=1e-5)  # the section's area from a 1024-point polygon


@pytest.mark.mpi
def test_a_file_without_tags_or_fields_is_refused(comm, mpi_tmp_path):
    import dolfinx
    from textile_fenicsx.volume.files import read_volume

    msh = dolfinx.mesh.create_unit_cube(comm, 2, 2, 2)
    with dolfinx.io.XDMFFile(comm, mpi_tmp_path / "bare.xdmf", "w") as f:
        f.write_mesh(msh)
    with pytest.raises(FormatError, match=r"bare.xdmf: no phase, direction, yarn_vf in this XDMF file"):
        read_volume(mpi_tmp_path / "bare.xdmf", comm)


def test_voxel_overlap_is_counted_and_given_to_the_deeper_yarn():
    t = cross_ply(gap=-0.1)  # the layers overlap 0.1 mm deep where the yarns cross
    vm = volume_mesh(t, VolumeOptions("voxel", 0.05, yarn_vf=0.6), MPI.COMM_SELF)
    overlap = vm.report["overlap"]
    lens = 4 * 0.1 * 1.6 * 1.6 * 0.6  # four crossings, 0.1 mm deep at most: the order of the lens volume
    assert overlap["voxels"] > 0 and 0.1 * lens < overlap["volume"] < 2 * lens
    assert {tuple(p["yarns"]) for p in overlap["pairs"]} == {("warp 0", "weft 0"), ("warp 0", "weft 1"),
                                                             ("warp 1", "weft 0"), ("warp 1", "weft 1")}
    # the deepest rule: above the crossing's mid-plane (z > 0) the warp (upper yarn) is deeper
    centres = vm.points[vm.cells].mean(axis=1)
    inside = t.inside(centres)
    both = inside[:, :2].any(axis=1) & inside[:, 2:].any(axis=1)
    assert both.sum() == overlap["voxels"]
    # near a crossing's centre (within 0.1 mm in plan) the warp's bottom and the weft's top are at -+0.05 mm
    # to 1.2 um: a centre above z = 0.001 lies deeper in the warp, one below -0.001 deeper in the weft
    near = np.all(np.abs(np.mod(centres[:, :2], 2.0) - 1.0) < 0.1, axis=1) & both
    assert np.all(np.isin(vm.phase[near & (centres[:, 2] > 0.001)], (1, 2)))
    assert np.all(np.isin(vm.phase[near & (centres[:, 2] < -0.001)], (3, 4)))
    assert np.sum(near & (centres[:, 2] > 0.001)) > 10


def test_periodicity_check_finds_a_broken_node():
    box = Box((0, 0, 0), (1, 1, 1))
    g = np.linspace(0, 1, 3)
    pts = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
    assert periodic_mismatch(pts, box)["periodic"]
    bad = pts.copy()
    bad[np.flatnonzero(bad[:, 0] == 1)[4], 1] += 1e-6  # a node on x+ moved off its image
    report = periodic_mismatch(bad, box)
    assert not report["periodic"] and report["x"]["missing"] == 1 and report["y"]["missing"] == 0
    assert report["x"]["example"] == bad[np.flatnonzero(bad[:, 0] == 1)[4]].tolist()


@pytest.mark.serial
def test_volume_mesh_command_errors_name_the_culprit(tmp_path):
    def run(*args):
        return subprocess.run(["textile-fenicsx", "volume-mesh", *args], capture_output=True, text=True, timeout=120)

    out = tmp_path / "vol"
    r = run("reference/models/plain.tg3", "--kind", "voxel", "--size", "0.0011", "--out", str(out))
    assert r.returncode == 2 and "would give" in r.stderr and "voxels, more than the limit" in r.stderr
    r = run("reference/models/plain.tg3", "--kind", "voxel", "--yarn-vf", "0.95", "--out", str(out))
    assert r.returncode == 2 and "--yarn-vf" in r.stderr and "0.9069" in r.stderr
    # a linear density 10 x too large (TexGen takes the fibre area from linear density / density first):
    # 10 x the fibre area, far above the densest packing of round fibres
    dense = tmp_path / "dense.tg3"
    text = Path("reference/models/satin4_fibres.tg3").read_text()
    dense.write_text(text.replace('LinearDensityValue="1.200000000000e+03"', 'LinearDensityValue="1.200000000000e+04"'))
    r = run(str(dense), "--kind", "voxel", "--out", str(out))
    assert r.returncode == 2 and "yarn 0: its fibre data give" in r.stderr and "densest packing" in r.stderr
    r = run("reference/models/plain.tg3", "--kind", "tet", "--out", str(out))
    assert r.returncode == 2 and "overlap at (" in r.stderr and "--kind voxel" in r.stderr
    assert not out.exists()


def test_tet_sizes_beyond_the_bounds_are_refused():
    from textile_fenicsx.volume.tet.options import TetOptions, check_size

    lo, hi = np.zeros(3), np.array([11.2, 11.2, 1.0])
    with pytest.raises(TextileError, match=r"tet size 0.01 mm would give about 4.64e\+09 tets, more than the limit"):
        check_size(lo, hi, TetOptions(size=0.01))
    with pytest.raises(TextileError, match=r"tet size 0.05 mm would give about .* tets and need about .* GB"):
        check_size(lo, hi, TetOptions(size=0.05, max_elements=10**9, memory_limit=1.0))


def test_default_voxels_resolve_the_thinnest_yarn_per_axis(caplog):
    # the cross-ply's yarns are ellipses 0.3 mm tall and 1.6 mm wide in a 4 x 4 x 0.7 mm cell: the
    # default rule (volume/voxel_sizes.py) asks for 8 voxels across 0.3 mm through the thickness and
    # 12 across 1.6 mm in plan, each count rounded up (0.7 / 0.0375 = 18.7 -> 19; 4 / 0.133 = 30).
    # That grid's centres miss 3.6 % of the yarns (their flat tops fall between two layers of
    # centres); the phase search takes the nearest finer grid within 0.25 %: 33 x 33 x 20 (+0.14 %)
    from textile_fenicsx.volume.box import cell_box
    from textile_fenicsx.volume.voxel import PHASE_TOLERANCE, default_grid

    with caplog.at_level("WARNING", logger="textile_fenicsx.volume.voxel"):
        vm = volume_mesh(cross_ply(), VolumeOptions("voxel", yarn_vf=0.6), MPI.COMM_SELF)
    sizes, phase = vm.report["sizes"], vm.report["sizes"]["phase"]
    assert phase["start_grid"] == [30, 30, 19], "the rule's counts, one per axis"
    assert phase["start_grid_fraction_error"] == pytest.approx(-0.036, abs=0.002), "its centres miss the flat tops"
    assert vm.report["voxels"] == [33, 33, 20], "the nearest finer grid that holds the yarn fraction"
    assert abs(phase["fraction_error"]) <= PHASE_TOLERANCE, "within the search's tolerance"
    assert sizes["thinnest"]["height_mm"] == pytest.approx(0.3, rel=1e-9), "the yarns' height, from their sections"
    assert 8 <= sizes["thinnest"]["voxels_across"] < 9.2, "at least 8 through the thinnest yarn, at most 3 steps more"
    assert 12 <= sizes["narrowest"]["voxels_across"] < 14, "12 or more across the narrowest width, 7 steps more at most"
    assert not sizes["capped"] and sizes["asked_mm"] is None and sizes["fraction_of_rule"] == 1, "the rule, uncapped"
    assert "voxels across its" not in caplog.text, "a grid that meets the rule is not warned about"
    # layers given: the default in plan, those layers through the thickness (4.3 across: warned)
    with caplog.at_level("WARNING", logger="textile_fenicsx.volume.voxel"):
        vm = volume_mesh(cross_ply(), VolumeOptions("voxel", layers=10, yarn_vf=0.6), MPI.COMM_SELF)
    assert vm.report["voxels"][2] == 10 and vm.report["voxels"][0] >= 30, "the layers asked, the rule in plan"
    assert "warp 0 is 4.3 voxels across its height" in caplog.text, "fewer layers than the rule's are warned about"
    # TexGen's plain weave (yarns 0.3 mm tall, 1.8 mm wide, a 4 x 4 x 0.6 mm cell): 27 x 27 x 16, the
    # rule's own grid (+0.18 %), the default whose stiffness docs/volume.md measures
    plain = load_model("reference/models/plain.tg3")
    counts, rule, search = default_grid(plain, cell_box(plain))
    assert counts == (27, 27, 16) and search["grids_tried"] == 1, "the plain weave's default grid, as measured"
    assert rule.sizes[2] <= 0.3 / 8 and rule.sizes[0] <= 1.8 / 12, "each voxel at most the rule's size"


@pytest.mark.mpi
def test_default_voxel_sizes_are_one_grid_on_every_rank(comm):
    # the default sizes are chosen on rank 0 with the mesh, and every rank reports the same grid; the
    # distributed mesh holds each of its voxels once
    cell = mesh_cell(cross_ply(), VolumeOptions("voxel", yarn_vf=0.6), comm)
    assert comm.allgather(cell.report["voxels"]) == [[33, 33, 20]] * comm.size, "one default grid on every rank"
    cells = cell.fields.mesh.topology.index_map(3).size_local
    assert comm.allreduce(cells, op=MPI.SUM) == 33 * 33 * 20, "every voxel on one rank exactly"


def test_voxel_sizes_per_axis_give_the_counts_asked():
    # (HX, HY, HZ): 4 / 0.2, 4 / 0.4 and 0.7 / 0.05 voxels, each the nearest whole number
    t = cross_ply()
    vm = volume_mesh(t, VolumeOptions("voxel", (0.2, 0.4, 0.05), yarn_vf=0.6), MPI.COMM_SELF)
    assert vm.report["voxels"] == [20, 10, 14], "one count per axis, from that axis's size"
    assert vm.report["sizes"]["asked_mm"] == [0.2, 0.4, 0.05], "the sizes asked are reported as given"
    # one size is that size along every axis: the same grid and phases as three equal sizes
    one = volume_mesh(t, VolumeOptions("voxel", 0.2, yarn_vf=0.6), MPI.COMM_SELF)
    three = volume_mesh(t, VolumeOptions("voxel", (0.2, 0.2, 0.2), yarn_vf=0.6), MPI.COMM_SELF)
    assert one.report["voxels"] == three.report["voxels"] == [20, 20, 3], "H is H H H (3 layers: 0.7 / 0.2 = 3.5-)"
    assert np.array_equal(one.phase, three.phase), "the same voxels, phase by phase"


def test_a_grid_coarser_than_the_rule_is_warned_with_the_error_to_expect(caplog):
    # 0.1 mm voxels put 3 across the cross-ply's 0.3 mm yarns (the rule: 8) and 16 across their
    # 1.6 mm width (the rule: 12): the warning names the yarn, its count, the rule and the error
    # measured at 3/8 of the rule's resolution
    from textile_fenicsx.volume.voxel_sizes import expected_error

    with caplog.at_level("WARNING", logger="textile_fenicsx.volume.voxel"):
        vm = volume_mesh(cross_ply(), VolumeOptions("voxel", 0.1, yarn_vf=0.6), MPI.COMM_SELF)
    assert "warp 0 is 3.0 voxels across its height of 0.3 mm (the rule: 8)" in caplog.text, caplog.text
    assert "across its width" not in caplog.text, "16 voxels across the width meet the rule's 12"
    r = vm.report["sizes"]["fraction_of_rule"]
    assert r == pytest.approx(3 / 8, rel=1e-3), "the grid has 3/8 of the rule's voxels across the height"
    assert expected_error(3 / 8) > expected_error(1.0), "a coarser grid is expected to be further off"
    assert f"expect Ex, Ez and Gxy off by up to about {expected_error(r):.0f} %" in caplog.text, caplog.text


def test_a_grid_at_a_poor_phase_is_warned_with_its_yarn_fraction(caplog):
    # the cross-ply's rule grid asked as sizes, 30 x 30 x 19: it meets the rule (no resolution
    # warning), but its centres miss 3.6 % of the yarns, which the warning gives with the error it
    # alone brings (Ex 1.1 % and Gxy 1.7 % per %: 3.9 and 6.1 %)
    with caplog.at_level("WARNING", logger="textile_fenicsx.volume.voxel"):
        vm = volume_mesh(cross_ply(), VolumeOptions("voxel", (4 / 30, 4 / 30, 0.7 / 19), yarn_vf=0.6), MPI.COMM_SELF)
    assert vm.report["voxels"] == [30, 30, 19], "the grid asked"
    assert vm.report["sizes"]["yarn_fraction_error"] == pytest.approx(-0.036, abs=0.002), "3.6 % of the yarns missed"
    assert "voxels across its" not in caplog.text, "it meets the rule"
    assert "yarn fraction is -3.6 % off the model's" in caplog.text, caplog.text
    assert "expect Ex off by about 3.9 % and Gxy by 6.1 % more from it alone" in caplog.text, caplog.text


def test_a_default_grid_too_large_is_coarsened_and_says_so(monkeypatch, caplog):
    # where the rule's grid would exceed DEFAULT_MAX_VOXELS, the three sizes grow by one factor until
    # it fits, and the warning says the default is coarser than the rule
    from textile_fenicsx.volume import voxel_sizes

    monkeypatch.setattr(voxel_sizes, "DEFAULT_MAX_VOXELS", 2000)
    with caplog.at_level("WARNING", logger="textile_fenicsx.volume.voxel"):
        vm = volume_mesh(cross_ply(), VolumeOptions("voxel", yarn_vf=0.6), MPI.COMM_SELF)
    counts = vm.report["voxels"]
    assert np.prod(counts) <= 2000 and vm.report["sizes"]["capped"], "the default fits the cap"
    assert np.prod(counts) > 2000 / 1.01**3 / 1.5, "and is no coarser than the cap needs (1 % steps, rounding)"
    assert "more than 2000 voxels, so the default is coarser" in caplog.text, caplog.text


@pytest.mark.serial
def test_voxel_sizes_on_the_command_line(tmp_path):
    # `--size HX HY HZ` gives those counts; a bad size (negative, two of them, three for a tet mesh,
    # and on solve two for --volume-size) exits 2 naming it, before any work: no output
    model = saved_cross_ply(tmp_path)
    r = run("volume-mesh", str(model), "--kind", "voxel", "--size", "0.2", "0.4", "0.05", "--yarn-vf", "0.6",
            "--out", str(tmp_path / "vol"))
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "vol" / "mesh_report.json").read_text())["voxels"] == [20, 10, 14], "HX HY HZ"
    out = tmp_path / "bad"
    for args, words in ((["volume-mesh", str(model), "--kind", "voxel", "--size", "-0.1"],
                         "volume mesh size must be > 0, got -0.1"),
                        (["volume-mesh", str(model), "--kind", "voxel", "--size", "0.1", "0.2"],
                         "--size takes one size H or three HX HY HZ [mm], got 2: 0.1 0.2"),
                        (["volume-mesh", str(model), "--kind", "tet", "--size", "0.3", "0.3", "0.1"],
                         "--size takes one size H [mm] for a tet mesh, got 3: 0.3 0.3 0.1"),
                        (["solve", "plain", "--volume-mesh", "voxel", "--volume-size", "0.1", "0.1"],
                         "--volume-size takes one size H or three HX HY HZ [mm], got 2: 0.1 0.1")):
        r = run(*args, "--out", str(out))
        assert r.returncode == 2 and words in r.stderr, (args, r.stderr[-2000:])
        assert not out.exists(), "nothing written"


def test_options_are_checked():
    with pytest.raises(TextileError, match="kind must be one of voxel, tet"):
        VolumeOptions("hex")
    with pytest.raises(TextileError, match="volume mesh size must be > 0"):
        VolumeOptions("voxel", -1)
    with pytest.raises(TextileError, match="volume mesh size must be > 0"):
        VolumeOptions("voxel", (0.1, -0.1, 0.1))
    with pytest.raises(TextileError, match=r"a voxel mesh takes one size H or three HX HY HZ \[mm\], got 2"):
        VolumeOptions("voxel", (0.1, 0.2))
    with pytest.raises(TextileError, match=r"a voxel mesh takes one size H or three HX HY HZ \[mm\], got 4"):
        VolumeOptions("voxel", (0.1, 0.1, 0.1, 0.1))
    with pytest.raises(TextileError, match=r"a tet mesh takes one size H \[mm\], got 3"):
        VolumeOptions("tet", (0.3, 0.3, 0.1))


@pytest.mark.serial
def test_volume_mesh_then_homogenise_commands(tmp_path):
    # the commands as a user runs them, on the cross-ply: the mesh folder, then stiffness.json, whose
    # C lies between the Voigt and Reuss bounds, and its in-plane constants are those of a balanced
    # cross-ply (Ex = Ey, Gxz = Gyz: the model's 90-degree rotation), to the solver's tolerance
    model = saved_cross_ply(tmp_path)

    r = run("volume-mesh", str(model), "--kind", "voxel", "--size", "0.2", "--yarn-vf", "0.6", "--out",
            str(tmp_path / "vol"))
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[0].startswith("voxel mesh: 1200 elements, Vf ")  # 20 x 20 x 3
    r = run("homogenise", str(tmp_path / "vol" / "volume.xdmf"), "--fibre", "e-glass", "--matrix", "epoxy",
            "--degree", "1", "--out", str(tmp_path / "h"))
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "h" / "stiffness.json").read_text())
    assert s["voigt_order"] == ["11", "22", "33", "23", "13", "12"]
    c = s["engineering_constants"]
    assert c["Ex"] == pytest.approx(c["Ey"], rel=1e-6) and c["Gxz"] == pytest.approx(c["Gyz"], rel=1e-6)
    assert s["checks"]["min_eig_C"] > 0 and s["checks"]["min_eig_voigt_minus_C"] > -1e-12
    assert s["checks"]["min_eig_C_minus_reuss"] > -1e-12
    assert r.stdout.startswith("Ex ") and "Vf 0." in r.stdout


@pytest.mark.serial
def test_homogenise_command_errors_name_the_culprit(tmp_path):
    import dolfinx

    def run(*args):
        return subprocess.run(["textile-fenicsx", "homogenise", *args], capture_output=True, text=True, timeout=300)

    bare = tmp_path / "bare.xdmf"
    with dolfinx.io.XDMFFile(MPI.COMM_SELF, bare, "w") as f:
        f.write_mesh(dolfinx.mesh.create_unit_cube(MPI.COMM_SELF, 2, 2, 2))
    out = tmp_path / "h"
    r = run(str(bare), "--out", str(out))
    assert r.returncode == 2 and "bare.xdmf: no phase, direction, yarn_vf in this XDMF file" in r.stderr
    r = run(str(bare), "--fibre", "kevlar", "--out", str(out))
    assert r.returncode == 2 and "unknown material 'kevlar'" in r.stderr
    bad = tmp_path / "fibre.toml"
    bad.write_text('symmetry = "isotropic"\nE = 70000\n')
    r = run(str(bare), "--fibre", str(bad), "--out", str(out))
    assert r.returncode == 2 and "fibre.toml" in r.stderr and "nu" in r.stderr
    assert not out.exists()


@pytest.mark.serial
def test_solve_then_tet_mesh_holds_the_gap_it_meshes_for(tmp_path):
    # `solve --volume-mesh tet --min-gap G`: the contact solve holds G between yarns (no volume lost),
    # and the tet mesh of the corrected cell is made for that same G, periodic
    out = tmp_path / "run"
    r = subprocess.run(["textile-fenicsx", "solve", "reference/models/plain.tg3", "--seed", "1.0", "--no-figures",
                        "--volume-mesh", "tet", "--volume-size", "0.5", "--min-gap", "0.02", "--out", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    report = json.loads((out / "mesh_report.json").read_text())
    assert metrics["solver"]["min_gap"] == 0.02 and report["policy"]["gap_mm"] == 0.02
    assert report["policy"]["least_gap_in_model_mm"] >= 0.75 * 0.02 and report["policy"]["volume_lost_percent"] == 0
    assert report["periodicity"]["periodic"] and all(abs(y["relative_error"]) < 0.01 for y in report["yarns"])
    assert "tet mesh: " in r.stdout and (out / "volume.xdmf").is_file() and (out / "volume.inp").is_file()
