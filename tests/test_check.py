"""The check after every run (verify.py) and the run that fails it (issue 13)."""

import json
import subprocess

import numpy as np
import pytest

from conftest import REPO
from textile_fenicsx.correction.verify import self_intersecting
from textile_fenicsx.model.sections import Ellipse, Polygon

CLI = ["python3", "-m", "textile_fenicsx"]


@pytest.mark.serial
def test_self_intersection_of_polygons():
    # a convex polygon and a star do not cross themselves; a bow tie (a square with two corners
    # swapped) does
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    ellipse = Ellipse(2.0, 0.5).points(64)
    star = np.array([[np.cos(a) * r, np.sin(a) * r] for a, r in
                     zip(np.linspace(0, 2 * np.pi, 10, endpoint=False), [1, 0.4] * 5)])
    bow = square[[0, 2, 1, 3]]
    assert list(self_intersecting(np.array([ellipse]))) == [False]
    assert list(self_intersecting(np.array([square, bow]))) == [False, True]
    assert list(self_intersecting(np.array([star]))) == [False]
    assert Polygon(tuple(map(tuple, star))).area() > 0  # a star is simple: anticlockwise, positive
    # a pentagram turns the same way at every vertex, but twice round: it crosses itself
    pentagram = np.array([[np.cos(a), np.sin(a)] for a in np.arange(5) * 4 * np.pi / 5])
    assert list(self_intersecting(np.array([pentagram]))) == [True]


@pytest.mark.serial
def test_the_convex_shortcut_of_the_self_intersection_check_changes_no_answer():
    # convex polygons skip the test of every pair of edges: on ellipses, their perturbations (some
    # convex, some not, some crossing themselves) and random polygons the answers are those of the
    # full test
    from textile_fenicsx.correction.verify import _edges_cross

    rng = np.random.default_rng(3)
    base = Ellipse(2.0, 0.5).points(32)
    polys = [base, base[::-1]] + [base + rng.normal(0, s, base.shape)
                                  for s in (1e-3, 1e-2, 0.05, 0.2) for _ in range(50)]
    polys += [rng.random((32, 2)) for _ in range(50)]
    polys = np.array(polys)
    fast, full = self_intersecting(polys), _edges_cross(polys)
    assert np.array_equal(fast, full) and 0 < fast.sum() < len(polys)


@pytest.mark.serial
def test_penalty_run_fails_its_check_and_keeps_its_outputs(tmp_path):
    # the paper's penalty leaves 1-4 % of the initial overlap (issue 13): the check says so, the
    # run exits 1 naming the numbers and the worst place, and keeps everything under clear names
    out = tmp_path / "run"
    run = subprocess.run(CLI + ["solve", str(REPO / "reference" / "models" / "plain.tg3"), "--seed", "0.5",
                                "--method", "penalty", "--no-figures", "--out", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 1, run.stderr[-2000:]
    assert "fails its check" in run.stderr and "overlap" in run.stderr and "deepest between" in run.stderr
    assert "finer --seed" not in run.stderr
    names = sorted(p.name for p in out.iterdir())
    assert "rejected.tg3" in names and "FAILED" in names and "corrected.tg3" not in names
    m = json.loads((out / "metrics.json").read_text())
    assert m["verdict"]["passed"] is False
    before, after = m["interpenetration"]["before"]["volume"], m["interpenetration"]["after"]["volume"]
    assert after > 0.01 * before  # what the check refused
    assert any(f["check"] == "overlap volume" for f in m["verdict"]["failures"])


@pytest.mark.serial
def test_an_overlap_left_by_a_coarse_mesh_is_meshed_again_or_says_to_try_a_finer_seed(tmp_path):
    # TexGen's jammed plain weave at seed 0.5: 0.036 mm deep where four footprints nearly meet;
    # at 0.35 it passes (test_jammed_plain_weaves_pass_at_seed_0_35). By default the run is done
    # again there and passes, saying so; with --remesh 0 the message says to try it. The penalty
    # method's overlap (above) is its own and gets neither
    model = str(REPO / "reference" / "fabrics" / "plain_w0.98_h0.2_ellipse.tg3")
    run = subprocess.run(CLI + ["solve", model, "--seed", "0.5", "--no-figures", "--out", str(tmp_path / "again")],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "at seed 0.5 mm the corrected yarns overlap" in run.stderr and "meshing at 0.35 mm" in run.stderr
    assert "meshed again at 0.35 mm, the run at 0.5 mm overlapped" in run.stdout
    m = json.loads((tmp_path / "again" / "metrics.json").read_text())
    assert m["mesh"]["seed"] == pytest.approx(0.35) and m["verdict"]["passed"]
    assert [r["seed"] for r in m["remeshed"]] == [0.5] and "0.0357" in m["remeshed"][0]["failures"][0]
    run = subprocess.run(CLI + ["solve", model, "--seed", "0.5", "--remesh", "0", "--no-figures",
                                "--out", str(tmp_path / "once")], capture_output=True, text=True, timeout=300)
    assert run.returncode == 1, run.stderr[-2000:]
    assert "overlap" in run.stderr and "the plates were meshed at 0.5 mm: try a finer --seed" in run.stderr
    bad = subprocess.run(CLI + ["solve", model, "--remesh", "7"], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "remesh must be a whole number of times from 0 to 3, got 7" in bad.stderr


@pytest.mark.serial
def test_contradictory_stacking_is_reported_as_failed(tmp_path):
    # plain.tg3 with warp 0's heights swapped (0.15 <-> 0.45) is no weave: no position of the yarns
    # keeps every contact, and the run says so (exit 1), never "converged"
    text = (REPO / "reference" / "models" / "plain.tg3").read_text()
    a, b = text.index('<Yarn index="0"'), text.index('<Yarn index="1"')
    yarn = text[a:b].replace('1.500000000000e-01" Tangent', 'X" Tangent')
    yarn = yarn.replace('4.500000000000e-01" Tangent', '1.500000000000e-01" Tangent')
    yarn = yarn.replace('X" Tangent', '4.500000000000e-01" Tangent')
    model = tmp_path / "swapped.tg3"
    model.write_text(text[:a] + yarn + text[b:])
    run = subprocess.run(CLI + ["solve", str(model), "--seed", "0.5", "--no-figures", "--out", str(tmp_path / "run")],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 1
    assert "no position of the yarns keeps every contact" in run.stderr
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["FAILED", "log.json"]


@pytest.mark.serial
@pytest.mark.parametrize("name", ["plain", "twill22", "satin4"])
def test_reference_weaves_pass_their_check_by_default(name, tmp_path):
    # issue 13, done when: the default command on TexGen's plain, 2/2 twill and 4-harness satin
    # leaves <= 1 % of the overlap, <= 1 % of the thinnest yarn as depth, volumes per length within 1 %
    out = tmp_path / "run"
    run = subprocess.run(CLI + ["solve", str(REPO / "reference" / "models" / f"{name}.tg3"), "--seed", "0.5",
                                "--no-figures", "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    m = json.loads((out / "metrics.json").read_text())
    ip = m["interpenetration"]
    h_min = {"plain": 0.3, "twill22": 0.3, "satin4": 0.35}[name]  # reference/README.md
    assert m["verdict"]["passed"]
    assert ip["after"]["volume"] <= 0.01 * ip["before"]["volume"]
    assert ip["after"]["max_depth"] <= 0.01 * h_min
    assert max(map(abs, m["yarn_volume_per_length_change"])) <= 0.01
    assert max(map(abs, m["section_area_change"])) <= 0.01


def _arc_yarn(radius: float, angle: float, width: float, half_height: float, offset: float = 0.0):
    """A yarn along a circular arc of `radius` [mm] turning by `angle` [rad] in the xz plane, its
    centre of curvature below (a crest), with a rectangular section width x 2 half_height whose 64
    vertices include the corners (so that the surfaces sample it exactly), its centre `offset` [mm]
    above the path."""
    from textile_fenicsx.model.yarn import ConstantSection, Yarn

    phi = np.linspace(-angle / 2, angle / 2, 41)
    nodes = np.column_stack((radius * np.sin(phi), np.zeros_like(phi), radius * np.cos(phi)))
    a, b = width / 2, half_height
    sides = [np.linspace(p, q, 16, endpoint=False) for p, q in
             (((a, -b), (a, b)), ((a, b), (-a, b)), ((-a, b), (-a, -b)), ((-a, -b), (a, -b)))]
    rectangle = Polygon(tuple(map(tuple, np.roll(np.vstack(sides), -8, axis=0) + [0.0, offset])))
    return Yarn(nodes, ConstantSection(rectangle), "cubic", periodic=False, name="binder")


@pytest.mark.serial
def test_a_yarn_s_surface_holds_its_sections_area_per_length_unless_it_folds():
    # issue 27: the volume per length of a yarn measured from its own surface (the divergence
    # theorem) is its section's area where the path turns more gently than the section is thick
    # (Pappus: the centroid on the path); round a bend of radius R below the half-height h the
    # sections sweep backwards on the inside, w (h - R)^2 / 2 per radian, counted by tube().folded
    from textile_fenicsx.correction.verify import tube
    from textile_fenicsx.model.textile import Resolution

    fine = Resolution(spacing=0.002, section_points=64, per_segment=4)
    w, h, angle = 1.0, 0.1, np.pi / 2
    gentle = tube(_arc_yarn(0.5, angle, w, h), fine)
    assert gentle.folded == 0 and gentle.at is None
    assert gentle.length == pytest.approx(0.5 * angle, rel=1e-4)
    assert gentle.per_length == pytest.approx(w * 2 * h, rel=1e-3)
    tight = tube(_arc_yarn(0.05, angle, w, h), fine)
    assert tight.folded == pytest.approx(w * angle * (h - 0.05) ** 2 / 2, rel=0.05)
    assert np.hypot(tight.at[0], tight.at[2]) == pytest.approx(0.05, rel=1e-3)  # a point of the path


@pytest.mark.serial
def test_a_yarn_whose_sections_sit_off_its_path_holds_their_area_per_length_of_their_centroids():
    # issue 27: TexGen's refined sections (a Hybrid, flat at the path) sit below their path, so on
    # a crown a tube holds A (1 - k c) per length of its path and the corrected yarn, whose path is
    # on the centroids, seemed to gain that (t2.4's binder +1.09 %). Pappus: the volume is A times
    # the distance the centroid travels. Measured per length of the centroids' line, a section c
    # above a crest's path of radius R holds A, not A (1 + c / R)
    from textile_fenicsx.correction.verify import tube
    from textile_fenicsx.model.textile import Resolution

    fine = Resolution(spacing=0.002, section_points=64, per_segment=4)
    w, h, angle, radius, c = 1.0, 0.1, np.pi / 2, 0.5, 0.05
    off = tube(_arc_yarn(radius, angle, w, h, offset=c), fine)
    assert off.folded == 0
    assert off.volume / (angle * radius) == pytest.approx(w * 2 * h * (1 + c / radius), rel=3e-3)  # per path length
    assert off.length == pytest.approx(angle * (radius + c), rel=3e-3)
    assert off.per_length == pytest.approx(w * 2 * h, rel=1e-4)


@pytest.mark.serial
def test_the_centroids_of_sections_and_of_sections_with_no_area():
    # the centroids' line a yarn's volume per length is measured along: a triangle's centroid is
    # the mean of its corners (a repeated corner adds no area); a section shrunk to a point has
    # none, and the path stands in for it (not a 0 / 0 that would make the check pass on NaN)
    from textile_fenicsx.model.sections import polygon_centroids

    square = [[0, 0], [1, 0], [1, 1], [0, 1]]
    triangle = [[0, 0], [3, 0], [0, 3], [0, 3]]
    point = [[5, 5]] * 4
    c = polygon_centroids(np.array([square, triangle, point], float))
    assert np.allclose(c, [[0.5, 0.5], [1.0, 1.0], [0.0, 0.0]], atol=1e-15)  # (0, 0): the path


@pytest.mark.serial
def test_the_check_refuses_a_yarn_that_folds_over_and_names_it():
    # issue 27: TexGen's orthogonal binders came out of the correction folded at their corners,
    # every section's area kept (the check passed them): the check now measures the fold, and its
    # message names the yarn, the share of its volume and the place
    from textile_fenicsx.correction.verify import Tolerances, _surface_checks
    from textile_fenicsx.model.textile import Cell, Textile

    def textile(radius):
        return Textile(Cell(4.0, 4.0, periodic=False), [_arc_yarn(radius, np.pi / 2, 1.0, 0.1)], name="arc")

    out, verdict = {}, {"failures": []}
    _surface_checks(textile(0.5), textile(0.5), Tolerances(), out, verdict)
    assert verdict["failures"] == [] and out["yarn_folded_fraction"] == [0.0]
    _surface_checks(textile(0.5), textile(0.05), Tolerances(), out, verdict)
    # the volume its surface encloses per length is its sections' area still (Pappus counts the
    # folded volume negatively once and the sections' areas positively once more): only the fold says
    assert [f["check"] for f in verdict["failures"]] == ["fold"]
    fold = verdict["failures"][0]
    assert fold["yarn"] == 0 and fold["value"] == pytest.approx(0.125, rel=0.05)  # (h - R)^2 / (4 h R)
    assert "binder (yarn 0) folds over itself: 12" in fold["message"]
    assert "swept backwards" in fold["message"] and fold["at"] is not None


@pytest.mark.mpi
def test_a_tight_plain_weave_keeps_its_volume_per_length(comm):
    # issue 27: TexGen's plain weave of boxy (polygon) sections at width/spacing 0.9 gained 3.0 %
    # volume per length in its corrected model (the sections bend with the plates across their
    # width, their centroids 0.056 mm off the path, above it over a crest: a swept tube holds
    # A (1 - k . c) per length). With the path through the centroids: within 0.1 %, both measured
    # by the rays in the cell and from each yarn's surface, and the check passes
    from textile_fenicsx.io.tg3 import read_tg3
    from textile_fenicsx.pipeline.stages import Settings, run
    from textile_fenicsx.plate.mesh.projected import MeshOptions

    result = run(read_tg3(REPO / "reference" / "fabrics" / "plain_w0.9_h0.2_polygon.tg3"),
                 Settings(MeshOptions(0.5)), comm)
    m = result.metrics
    assert m["verdict"]["passed"], [f["message"] for f in m["verdict"]["failures"]]
    assert max(map(abs, m["yarn_volume_per_length_change"])) < 1e-3
    assert max(map(abs, m["yarn_surface_volume_per_length_change"])) < 1e-3
    assert max(m["yarn_volume_change"]) > 0.14  # the yarns are 15 % longer: more crimp, not more area
    assert m["after"]["interpenetration"]["volume"] == 0.0


def _jammed_plain(fabric: str):
    """The sweep's jammed plain weaves (width/spacing 0.98): TexGen's (bench/make_fabrics.py) and
    our builder's (`ours_plain_jammed`)."""
    from textile_fenicsx.io.tg3 import read_tg3
    from textile_fenicsx.model.weaves import build

    if fabric == "texgen":
        return read_tg3(REPO / "reference" / "fabrics" / "plain_w0.98_h0.2_ellipse.tg3")
    return build("plain", spacing=2.0, width=1.96, height=0.4)


@pytest.mark.mpi
@pytest.mark.parametrize("fabric", ["texgen", "ours"])
@pytest.mark.slow  # 10 s a fabric serially, 114-120 s under mpirun -n 2 (--durations, 2026-12-07): the slow tier
def test_jammed_plain_weaves_pass_at_seed_0_35(fabric, comm):
    # issue 27, item 3: the jammed plain weaves pass their check at seed 0.35, with no overlap left.
    # At seed 0.5 they still fail (docs/sweep.md): the plates' mesh does not resolve the corner
    # where the four footprints nearly meet
    from textile_fenicsx.pipeline.stages import Settings, run
    from textile_fenicsx.plate.mesh.projected import MeshOptions

    m = run(_jammed_plain(fabric), Settings(MeshOptions(0.35)), comm).metrics
    assert m["verdict"]["passed"], [f["message"] for f in m["verdict"]["failures"]]
    assert m["after"]["interpenetration"]["volume"] == 0.0
    # asked at 0.5 (Settings.remesh): TexGen's overlaps there, ours reaches the step cap; both are
    # done again at 0.35, the same run (to the last bit in serial; MUMPS' parallel factorisation is
    # not bit-reproducible on 2 ranks)
    again = run(_jammed_plain(fabric), Settings(MeshOptions(0.5)), comm)
    assert again.settings.mesh.seed == 0.35 and [r["seed"] for r in again.remeshed] == [0.5]
    why = "the corrected yarns overlap" if fabric == "texgen" else "reached its cap of 100 steps"
    assert why in again.remeshed[0]["failures"][0]
    assert again.verdict["passed"] and again.metrics["after"]["interpenetration"]["volume"] == 0.0
    for key in ("thickness", "crimp"):
        assert again.metrics["after"][key] == pytest.approx(m["after"][key], rel=1e-8)


@pytest.mark.slow
@pytest.mark.serial
def test_jammed_plain_weave_thickness_has_converged_at_seed_0_35():
    # the passing seed is a converged one: seed 0.25 gives the same thickness to 0.5 % (1.083 and
    # 1.084 mm on TexGen's), where seed 0.5 is 7 % thicker (1.160 mm: too coarse for this weave)
    from mpi4py import MPI

    from textile_fenicsx.pipeline.stages import Settings, run
    from textile_fenicsx.plate.mesh.projected import MeshOptions

    thickness = [run(_jammed_plain("texgen"), Settings(MeshOptions(seed)), MPI.COMM_WORLD).metrics["after"]["thickness"]
                 for seed in (0.35, 0.25)]
    assert thickness[0] == pytest.approx(thickness[1], rel=5e-3)
