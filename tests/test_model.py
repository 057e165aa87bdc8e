"""Textile model: sections, centrelines, queries and metrics against closed forms and TexGen."""

import json

import numpy as np
import pytest
from scipy.special import ellipe

from textile_fenicsx.io.tg3 import read_tg3
from textile_fenicsx.model.metrics import _clipped, coverage_depth, crimp, measure
from textile_fenicsx.model.sections import Ellipse, Lenticular, PowerEllipse, polygon_area
from textile_fenicsx.model.textile import Cell, Resolution, Textile
from textile_fenicsx.model.weaves import build, crowfoot_satin, orthogonal, plain, satin, twill
from textile_fenicsx.model.yarn import ConstantSection, Yarn

FABRICS = ["plain", "twill22", "satin4", "ortho"]


# --- sections: closed forms -----------------------------------------------------------------

@pytest.mark.serial
@pytest.mark.parametrize("n", [8, 40, 64])
def test_ellipse_polygon_area_is_the_inscribed_polygon_area(n):
    # n points uniform in the ellipse's angle parameter enclose exactly (n/2) a b sin(2 pi / n).
    e = Ellipse(2.5, 0.35)
    a, b = e.width / 2, e.height / 2
    assert polygon_area(e.points(n)) == pytest.approx(n / 2 * a * b * np.sin(2 * np.pi / n), rel=1e-12)
    assert e.area() == pytest.approx(np.pi * a * b, rel=1e-15)


@pytest.mark.serial
@pytest.mark.parametrize("section", [PowerEllipse(3.6, 0.35, 0.6), PowerEllipse(1.4, 0.16, 0.8, 0.2),
                                     PowerEllipse(2.0, 0.5, 1.0), Lenticular(2.0, 0.5), Lenticular(2.0, 0.5, 0.1)])
def test_section_areas_match_closed_forms(section):
    # Power ellipse: w h sqrt(pi)/2 Gamma(p/2+1)/Gamma(p/2+3/2); lenticular: two circular segments.
    # A fine polygon converges to it; a 2x finer one is closer (the polygon error is O(n^-2)).
    e1 = abs(polygon_area(section.points(2000)) / section.area() - 1)
    e2 = abs(polygon_area(section.points(4000)) / section.area() - 1)
    assert e1 < 2e-5 and e2 < e1


@pytest.mark.serial
def test_power_one_is_the_ellipse_and_sections_start_at_plus_s():
    assert PowerEllipse(2, 1, 1.0).area() == pytest.approx(Ellipse(2, 1).area(), rel=1e-14)
    for s in (Ellipse(2, 1), PowerEllipse(2, 1, 0.6), Lenticular(2, 1, 0.2)):
        p = s.points(16)
        assert p[0, 0] == pytest.approx(1.0) and polygon_area(p) > 0  # +s extreme, anticlockwise
        assert p[4, 1] == pytest.approx(0.5)  # quarter turn: the top


# --- yarns: closed forms --------------------------------------------------------------------

def _straight_yarn(L=4.0, y=1.0, z=0.2, section=None, interpolation="bezier"):
    section = Ellipse(1.5, 0.3) if section is None else section
    nodes = [[0, y, z], [L / 2, y, z], [L, y, z]]
    return Yarn(nodes, ConstantSection(section), interpolation, repeats=[[L, 0, 0], [0, 2.0, 0]])


@pytest.mark.mpi
@pytest.mark.parametrize("interpolation", ["bezier", "cubic", "linear"])
def test_straight_yarn_volume_is_area_times_length(interpolation, comm):
    K = 64
    t = Textile(Cell(4.0, 2.0), [_straight_yarn(interpolation=interpolation)], resolution=Resolution(0.1, K))
    m = measure(t, 400, comm=comm)
    exact = polygon_area(Ellipse(1.5, 0.3).points(K)) * 4.0
    # Grid midpoint rule over the section's width: error from the sqrt-shaped edges, ~1e-4 here.
    assert m["yarn_volume"]["total"] == pytest.approx(exact, rel=5e-4)
    assert m["thickness"] == pytest.approx(0.3, abs=1e-3)
    assert m["crimp"] == [pytest.approx(0.0, abs=1e-12)]
    assert m["interpenetration"]["volume"] == 0.0


@pytest.mark.serial
@pytest.mark.parametrize("amplitude", [0.1, 0.3])
def test_crimp_of_a_sinusoidal_path(amplitude):
    # z = A sin(2 pi x / L): length / L = (2/pi) sqrt(1 + m^2) E(m^2 / (1 + m^2)), m = 2 pi A / L.
    L, n = 5.0, 64
    x = np.linspace(0, L, n + 1)
    nodes = np.column_stack((x, np.zeros_like(x), amplitude * np.sin(2 * np.pi * x / L)))
    yarn = Yarn(nodes, ConstantSection(Ellipse(1, 0.1)), "cubic", repeats=[[L, 0, 0]])
    m = 2 * np.pi * amplitude / L
    exact = 2 / np.pi * np.sqrt(1 + m * m) * ellipe(m * m / (1 + m * m)) - 1
    t = Textile(Cell(L, 1.0), [yarn])
    assert crimp(t)[0] == pytest.approx(exact, rel=1e-4)


@pytest.mark.serial
def test_bezier_follows_texgen_rule():
    # Control points at P_i + T_i |P_{i+1} - P_i| / 3 with in-plane node tangents: a flat float
    # between two equal-height nodes stays exactly flat, and the midpoint of a rise is halfway up.
    nodes = [[0, 0, 0], [2, 0, 0], [4, 0, 1], [6, 0, 0]]
    y = Yarn(nodes, ConstantSection(Ellipse(1, 0.2)), "bezier", tangents=np.tile([1.0, 0, 0], (4, 1)))
    pos, tan = y.centreline(np.array([0.5, 1.5, 2.5]))
    assert pos[0, 2] == 0.0 and np.allclose(tan[0], [1, 0, 0])
    assert pos[1] == pytest.approx([3.0, 0, 0.5])


@pytest.mark.serial
def test_periodic_cubic_is_c2_across_the_seam():
    x = np.linspace(0, 4, 5)
    nodes = np.column_stack((x, 0.3 * np.cos(np.pi * x / 2) ** 2, 0.1 * np.sin(np.pi * x / 2)))
    y = Yarn(nodes, ConstantSection(Ellipse(1, 0.2)), "cubic")
    spline, drift = y._cubic()
    for d in (1, 2):
        assert np.allclose(spline(0.0, d), spline(4.0, d), atol=1e-12)
    assert np.allclose(y.centreline(np.array([4.0]))[0], nodes[-1])


# --- queries --------------------------------------------------------------------------------

@pytest.mark.serial
def test_inside_and_fibre_direction():
    t = build("crowfoot_satin", spacing=2.8, width=2.5, height=0.35, thickness=0.7)
    # warp 0 at y = 1.4 is under weft 0 at x = 1.4 (pattern 0): centre z = 0.175
    hit = t.inside([[1.4, 1.4, 0.175], [1.4, 1.4, 0.525], [1.4, 1.4, 0.8]])
    assert hit[0, 0] and not hit[0, 4]
    assert hit[1, 4] and not hit[1, 0]  # weft 0 is on top there
    assert not hit[2].any()
    d = t.fibre_direction(0, np.array([[5.6, 1.4], [0.1, 1.4]]))
    assert np.allclose(d[0], [1, 0, 0], atol=1e-6)  # on the float: flat, along x
    assert abs(d[1, 0]) > 0.95 and abs(d[1, 2]) > 0.1 and d[1, 1] == pytest.approx(0, abs=1e-12)  # rising
    d = t.fibre_direction(4, np.array([[1.4, 7.0]]))
    assert np.allclose(np.abs(d[0, 1]), 1.0, atol=1e-6)


@pytest.mark.serial
def test_a_point_beyond_the_cell_takes_its_direction_from_the_copy_that_holds_it():
    # A volume mesh's box may start off the cell's origin (the tet mesher moves it off the yarns' edges), so
    # elements lie in copies of a yarn whose centrelines never meet the cell. Periodicity: the
    # nearest centreline point of a translated point is the translated nearest point.
    t = build("crowfoot_satin", spacing=2.8, width=2.5, height=0.35, thickness=0.7)
    pos, tan = t.nearest_centreline(0, np.array([[5.6, 1.4, 0.3]]))  # weft 0 along x at y = 1.4
    for shift in ([0.0, 11.2, 0.0], [11.2, 11.2, 0.0], [-11.2, 11.2, 0.0]):
        far_pos, far_tan = t.nearest_centreline(0, pos + shift)
        assert np.allclose(far_pos, pos + shift, atol=1e-9)
        assert np.allclose(far_tan, tan, atol=1e-12)


@pytest.mark.serial
def test_the_fibre_direction_follows_a_binder_round_its_corners(reference_dir):
    # TexGen's orthogonal binders turn round corners of about 0.1 mm radius. At points on the
    # centreline (sampled 100 times finer than the directions' samples), the direction given is
    # within the 2 degrees the volume meshes promise of the tangent there (the quarter-spacing
    # samples alone were 6 degrees off).
    t = read_tg3(reference_dir / "models" / "ortho.tg3")
    for i, y in enumerate(t.yarns):
        pos, tan = y.centreline(y.stations(t.resolution.spacing / 400))
        cos = np.abs(np.einsum("ij,ij->i", t.fibre_direction(i, pos), tan))
        assert np.degrees(np.arccos(np.clip(cos, 0.0, 1.0))).max() < 2.0, y.name

@pytest.mark.mpi
def test_metrics_do_not_depend_on_where_the_cell_starts(comm):
    # Periodicity: the same fabric sampled over a shifted cell has the same volumes.
    a = build("twill", spacing=2.0, width=1.8, height=0.3, thickness=0.55)
    b = build("twill", spacing=2.0, width=1.8, height=0.3, thickness=0.55)
    b.cell = Cell(a.cell.lx, a.cell.ly, 0.77, -0.31)
    ma, mb = measure(a, 200, comm), measure(b, 200, comm)
    # The grid's midpoint rule across sqrt-shaped section edges errs by ~(h / width)^1.5 = 3e-3 here,
    # differently for each placement of the grid: that bounds the agreement.
    assert mb["yarn_volume"]["total"] == pytest.approx(ma["yarn_volume"]["total"], rel=5e-3)
    assert mb["interpenetration"]["volume"] == pytest.approx(ma["interpenetration"]["volume"], rel=2e-2)
    assert mb["thickness"] == pytest.approx(ma["thickness"], abs=1e-3)


@pytest.mark.mpi
def test_queries_split_over_ranks_agree_with_serial(comm):
    t = build("crowfoot_satin", spacing=2.8, width=2.5, height=0.35, thickness=0.7)
    serial = measure(t, 120)
    split = measure(t, 120, comm=comm)
    assert split["yarn_volume"]["per_yarn"] == pytest.approx(serial["yarn_volume"]["per_yarn"], rel=1e-12)
    assert split["interpenetration"]["volume"] == pytest.approx(serial["interpenetration"]["volume"], rel=1e-12)
    assert split["interpenetration"]["max_depth"] == serial["interpenetration"]["max_depth"]
    assert split["thickness"] == serial["thickness"]


# --- reference: TexGen's own numbers (reference/texgen_measurements.json) ------------

@pytest.fixture(scope="module")
def reference(reference_dir):
    data = json.loads((reference_dir / "texgen_measurements.json").read_text())
    return {k: (read_tg3(reference_dir / "models" / f"{k}.tg3"), data[k]["initial"]) for k in FABRICS}


@pytest.fixture(scope="module")
def measured(reference):
    return {k: measure(t, 200) for k, (t, _) in reference.items()}


@pytest.mark.serial
@pytest.mark.parametrize("fabric", FABRICS)
def test_reference_volume_and_thickness(fabric, reference, measured):
    _, ref = reference[fabric]
    m = measured[fabric]
    # Issue 3: within 1 %. TexGen's 40-point section polygons enclose 0.4 % less than the curve.
    assert m["yarn_volume"]["total"] == pytest.approx(ref["yarn_volume_sum_in_domain"], rel=0.01)
    for ours, theirs in zip(m["yarn_volume"]["per_yarn"], ref["yarns"]):
        assert ours == pytest.approx(theirs["volume_in_domain_grid"], rel=0.01)
    assert m["thickness"] == pytest.approx(ref["thickness"], rel=0.01)
    for ours, theirs in zip(m["crimp"], ref["yarns"]):
        assert ours == pytest.approx(theirs["crimp"], rel=5e-3, abs=1e-6)


@pytest.mark.serial
@pytest.mark.parametrize("fabric", ["plain", "twill22", "satin4"])
def test_reference_interpenetration_2d_weaves(fabric, reference, measured):
    _, ref = reference[fabric]
    m = measured[fabric]
    # Issue 3: initial interpenetration volume within 5 %; depth to the grid's z accuracy.
    assert m["interpenetration"]["volume"] == pytest.approx(ref["interpenetration"]["volume"], rel=0.05)
    assert m["interpenetration"]["max_depth"] == pytest.approx(ref["interpenetration"]["max_z_overlap"], abs=5e-3)
    assert len(m["interpenetration"]["pairs"]) == ref["interpenetration"]["n_overlapping_pairs"]


@pytest.mark.serial
def test_reference_interpenetration_orthogonal(reference, measured):
    # The orthogonal weave's overlap is a sliver where a binder's steep leg cuts a weft's edge:
    # 0.015 mm^3 in a 223 mm^3 cell. It depends on how the sections are polygonised (ours: 64 points,
    # TexGen: 40); we hold it to 0.005 mm^3 (2e-5 of the cell) and the same 8 pairs.
    # Its depth is the maximum of a ridge 0.056 mm wide at half height: 0.0308 mm over the plane
    # (0.0310-0.0312 mm with 40-128 section points, stations 0.1-0.05 mm apart), where the grid's
    # deepest column alone saw 0.0248 (issue 27, item 6). TexGen's 0.0317 mm is 3 of its 0.01056 mm
    # cells along z on the same 200 x 200 columns (0.0251 mm with 1600 cells); its own classifier on
    # columns 0.0025 mm apart around the ridge gives 0.0284 mm (its surfaces are not ours to 0.002 mm
    # there): we hold ours to TexGen's reference to 0.003 mm.
    _, ref = reference["ortho"]
    m = measured["ortho"]
    assert m["interpenetration"]["volume"] == pytest.approx(ref["interpenetration"]["volume"], abs=5e-3)
    assert m["interpenetration"]["max_depth"] == pytest.approx(0.0308, abs=3e-4)
    assert m["interpenetration"]["max_depth"] == pytest.approx(ref["interpenetration"]["max_z_overlap"], abs=3e-3)
    assert len(m["interpenetration"]["pairs"]) == ref["interpenetration"]["n_overlapping_pairs"]


@pytest.mark.mpi
def test_the_deepest_overlap_is_found_between_the_grids_columns(reference_dir, comm):
    # Issue 27, item 6: on TexGen's orthogonal weave the deepest overlap is a ridge where a binder's
    # steep leg cuts a weft's edge, 0.056 mm wide at half its height: the 200 x 200 grid's deepest
    # column saw 0.0248 mm of its 0.0308 (`report`, and the check's depth bound with it). Now a
    # dense scan around the place found (41 x 41 columns 0.0015 mm apart) finds nothing deeper.
    t = read_tg3(reference_dir / "models" / "ortho.tg3")
    ip = measure(t, 200, comm)["interpenetration"]
    assert ip["max_depth"] > 0.030
    g = np.linspace(-0.03, 0.03, 41)
    scan = np.array([(ip["at"][0] + a, ip["at"][1] + b) for a in g for b in g])
    col = t.columns(scan)
    bot, top = _clipped(t, col)
    assert coverage_depth(len(scan), col.point, bot, top).max() == pytest.approx(ip["max_depth"], abs=2e-4)
    assert max(p["max_depth"] for p in ip["pairs"]) == pytest.approx(ip["max_depth"], rel=1e-12)
    # the same on any number of ranks
    assert ip["max_depth"] == measure(t, 200)["interpenetration"]["max_depth"]


@pytest.mark.serial
def test_binned_triangles_give_the_crossings_of_vertical_hits(reference):
    # rays.TriangleBins (the deepest overlap's rounds of a few hundred points) finds the same
    # crossings, the same numbers, as vertical_hits, which bins the triangles at every call: points
    # scattered over the cell and beyond it, on the lattice the metrics' grid uses, and on the
    # triangles' own vertices and edges
    from textile_fenicsx.model.rays import TriangleBins, lattice, vertical_hits

    t, _ = reference["ortho"]
    rng = np.random.default_rng(3)
    x0, x1, y0, y1 = t.cell.bounds
    xy, _ = t.cell.grid(60)
    for i in (0, len(t.yarns) - 1):
        tris = t.triangles(i)
        bins = TriangleBins(tris, t.resolution.spacing)
        for pts in (rng.uniform((x0 - 0.5, y0 - 0.5), (x1 + 0.5, y1 + 0.5), (500, 2)), xy,
                    tris[:50, :, :2].reshape(-1, 2), tris[:50, :2, :2].mean(axis=1)):
            grid = lattice(pts) if pts is xy else None
            want = vertical_hits(tris, pts, t.resolution.spacing, grid)
            got = bins.hits(pts)
            a, b = np.lexsort((want[1], want[0])), np.lexsort((got[1], got[0]))
            assert np.array_equal(want[0][a], got[0][b]) and np.array_equal(want[1][a], got[1][b])
            assert len(want[0]) > 0


@pytest.mark.serial
def test_a_polygon_section_survives_pickling_unchanged():
    # Polygon pickles its vertices as one array (the figures' process gets the corrected model) and
    # comes back as __post_init__ left it: tuples of numpy floats, equal and of the same types
    import pickle

    from textile_fenicsx.model.sections import Polygon

    p = Polygon(tuple(map(tuple, Ellipse(2.5, 0.35).points(64) + [0.01, -0.02])))
    q = pickle.loads(pickle.dumps(p, protocol=pickle.HIGHEST_PROTOCOL))
    assert q == p and hash(q) == hash(p)
    assert [type(v) for row in q.vertices for v in row] == [type(v) for row in p.vertices for v in row]


@pytest.mark.serial
def test_crowfoot_builder_reproduces_texgen_satin(reference):
    # TexGen's satin4 (SwapPosition at (0,0), (1,1), (2,3), (3,2)) has the same master nodes as our
    # builder, shifted by half a spacing (TexGen's yarn 0 lies on y = 0).
    texgen, _ = reference["satin4"]
    ours = build("crowfoot_satin", spacing=2.8, width=2.5, height=0.35, thickness=0.7)
    for a, b in zip(ours.yarns, texgen.yarns):
        assert np.allclose(a.nodes, b.nodes + [1.4, 1.4, 0], atol=1e-12)
        assert a.section == b.section


# --- builders ------------------------------------------------------------------------------

@pytest.mark.serial
def test_patterns():
    assert plain().tolist() == [[1, 0], [0, 1]]
    assert twill(2, 2).tolist() == [[1, 1, 0, 0], [0, 1, 1, 0], [0, 0, 1, 1], [1, 0, 0, 1]]
    s = satin(5, 2)
    assert (s == 0).sum(axis=0).tolist() == [1] * 5 and (s == 0).sum(axis=1).tolist() == [1] * 5
    assert [tuple(x) for x in np.argwhere(crowfoot_satin() == 0)] == [(0, 0), (1, 1), (2, 3), (3, 2)]


@pytest.mark.serial
def test_orthogonal_structure():
    t = orthogonal()
    names = [y.name for y in t.yarns]
    assert sum(n.startswith("warp") for n in names) == 4 and sum(n.startswith("binder") for n in names) == 2
    assert sum(n.startswith("weft") for n in names) == 12
    assert (t.cell.lx, t.cell.ly) == (11.2, pytest.approx(10.4))
    m = measure(t, 100)
    # binders pass over the top weft layer and under the bottom one: thickness = stack + 2 binders
    # (+ under 0.01 mm where the Bezier turns of a binder overshoot its level)
    stack = 3 * 0.3 + 2 * 0.35
    assert stack + 2 * 0.16 - 1e-3 <= m["thickness"] <= stack + 2 * 0.16 + 0.01
