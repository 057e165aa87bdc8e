"""Sheared unit cells (docs/shear.md): the lattice, TexGen's sheared weaves read and written, the
builders' shear and jamming, and the default command on a sheared plain weave."""

import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.io.tg3 import read_tg3
from textile_fenicsx.io.tg3_write import write_tg3
from textile_fenicsx.model.textile import Cell, Textile
from textile_fenicsx.model.weaves import build, jamming_angle

DATA = Path(__file__).parent / "data" / "sheared"
REPO = Path(__file__).resolve().parent.parent


# --- the lattice ------------------------------------------------------------------------------

def test_wrap_moves_a_row_up_by_the_shift():
    # a1 = (4, 0), a2 = (1, 3): (x, y) is (x + 1, y + 3). By hand: (0.5, 3.5) is one row up, so
    # (0.5 - 1, 0.5) = (-0.5, 0.5), then +4 along x: (3.5, 0.5); (4.5, -0.5) one row down:
    # (5.5, 2.5) -> (1.5, 2.5); (1, 6.2) two rows up: (1 - 2, 0.2) -> (3, 0.2)
    c = Cell(4.0, 3.0, shift=1.0)
    got = c.wrap(np.array([[0.5, 3.5], [4.5, -0.5], [1.0, 6.2]]))
    assert np.allclose(got, [[3.5, 0.5], [1.5, 2.5], [3.0, 0.2]], atol=1e-14)


def test_lattice_vectors_and_neighbours():
    c = Cell(4.0, 3.0, x0=-1.0, y0=2.0, shift=1.0)
    assert np.array_equal(c.repeats, [[4, 0, 0], [1, 3, 0]])
    assert np.allclose(c.lattice_coordinates([[5.0, 3.0], [9.0, 6.0]]), [[1, 1], [1.75, 2]])
    assert np.allclose(c.nearest_translation([[5.1, 3.05]]), [[5, 3]])
    # the 9 cells around: each row's copies within half a cell of the cell along x (a shift of
    # 3 mm is brought back by one cell: -1 mm)
    n = Cell(4.0, 3.0, shift=3.0).neighbours()
    assert np.allclose(n[0], 0)
    assert sorted(map(tuple, np.round(n, 12))) == sorted(
        [(a, 0.0) for a in (0.0, -4.0, 4.0)] + [(a, 3.0) for a in (-1.0, -5.0, 3.0)]
        + [(a, -3.0) for a in (1.0, -3.0, 5.0)])
    assert c.shear_angle == pytest.approx(np.degrees(np.arctan(1 / 3)), abs=1e-12)
    assert Cell(4.0, 3.0).shear_angle == 0.0 and not Cell(4.0, 3.0).sheared


def test_degenerate_lattice_is_refused():
    with pytest.raises(TextileError, match="degenerate lattice"):
        Cell(4.0, 1.0, shift=10.0)  # 84 degrees: a2 nearly along a1
    with pytest.raises(TextileError, match="free edges"):
        Cell(4.0, 3.0, periodic=False, shift=1.0)


def _grid_mesh(nx: int, ny: int, lx: float, ly: float):
    """A structured triangulation of [0, lx] x [0, ly]: (nx + 1)(ny + 1) nodes, 2 nx ny triangles."""
    X, Y = np.meshgrid(np.linspace(0, lx, nx + 1), np.linspace(0, ly, ny + 1), indexing="ij")
    x = np.column_stack((X.ravel(), Y.ravel()))
    node = np.arange(len(x)).reshape(nx + 1, ny + 1)
    cells = [c for i in range(nx) for j in range(ny) for c in
             ((node[i, j], node[i + 1, j], node[i + 1, j + 1]), (node[i, j], node[i + 1, j + 1], node[i, j + 1]))]
    return x, np.array(cells, np.int64), np.zeros(len(cells), np.int32)


def test_ghost_strip_of_a_sheared_cell():
    # cell 2 x 1, shift 0.5, a grid of 0.5 mm: the bottom row's 4 cells with an edge on the side
    # go up by 1 and along x by 0.5, except the one over [1.5, 2], which 0.5 takes past the right
    # side: it goes back a whole cell, by -1.5, to [0, 0.5]. Their inner nodes (0.5, 1, 1.5, 2 at
    # y = 0.5) land at y = 1.5: 1, 1.5, 2 and 0.5; their side nodes are the top side's nodes
    from textile_fenicsx.plate.mesh.conversion import GHOST, ghost_strip

    cell = Cell(2.0, 1.0, shift=0.5)
    x, cells, tags = _grid_mesh(4, 2, 2.0, 1.0)
    X, C, T = ghost_strip(cell, x, cells, tags)
    new = X[len(x):]
    top = new[new[:, 1] > 1.25]
    assert np.allclose(np.sort(top[:, 0]), [0.5, 1.0, 1.5, 2.0]) and np.allclose(top[:, 1], 1.5)
    strip = C[len(cells):][T[len(cells):] == GHOST]
    above = strip[np.all(X[strip][..., 1] > 1 - 1e-12, axis=1)]
    assert len(strip) == 6 and len(above) == 4  # and the left column's 2 beyond the right side
    side = [sorted(np.round(X[c][X[c][:, 1] == 1.0][:, 0], 12)) for c in above]
    assert sorted(side) == [[0.0, 0.5], [0.5, 1.0], [1.0, 1.5], [1.5, 2.0]]


def test_side_marks_of_a_sheared_cell():
    # a chain crossing y = 1 (the top side) at x = 1.8 meets the bottom side's copy at 1.8 - 0.5 =
    # 1.3; a sheared cell's bottom side also gets the image of the top's corner, 0 - 0.5 + 2 = 1.5
    from textile_fenicsx.plate.mesh.periodic_sides import side_marks

    cell = Cell(2.0, 1.0, shift=0.5)
    on_x, on_y = side_marks([np.array([[1.7, 0.8], [1.9, 1.2]])], cell, 1e-3)
    assert np.allclose(on_y, [1.3, 1.5]) and len(on_x) == 0


# --- TexGen's sheared weaves ------------------------------------------------------------------

def test_read_texgen_sheared_plain():
    # CShearedTextileWeave2D(2, 2, 2.0, 0.56, 30 deg): x yarns 2 mm apart along the wefts, so
    # ly = 2 x 2 cos 30 = 3.4641 and the wefts' repeat (2 x 2 sin 30, ly) = (2, 3.4641); the sheared
    # domain's corner at (-1 + tan 30 x y0, y0), y0 = -ly / 4
    t = read_tg3(DATA / "plain_g30.tg3")
    c = t.cell
    assert (c.lx, c.shift) == (4.0, 2.0)
    assert c.ly == pytest.approx(4 * np.cos(np.radians(30)), abs=1e-12)
    assert c.y0 == pytest.approx(-c.ly / 4, abs=1e-12)
    assert c.x0 == pytest.approx(-1 + np.tan(np.radians(30)) * c.y0, abs=1e-12)
    assert c.shear_angle == pytest.approx(30, abs=1e-9)
    # the default domain (a box, AssignDefaultDomain()) is the same lattice
    box = read_tg3(DATA / "plain_g30_box.tg3").cell
    assert (box.lx, box.shift, box.x0) == (4.0, 2.0, -1.5) and box.ly == pytest.approx(c.ly, abs=1e-12)


@pytest.mark.parametrize("name,angle", [("plain_g0", 0), ("twill22_g15", 15), ("satin4_g40", 40)])
def test_read_texgen_sheared_angles(name, angle):
    t = read_tg3(DATA / f"{name}.tg3")
    n = 2 if name.startswith("plain") else 4
    assert t.cell.shear_angle == pytest.approx(angle, abs=1e-9)
    assert t.cell.area == pytest.approx((2.0 * n) ** 2 * np.cos(np.radians(angle)), rel=1e-12)


def test_written_domain_is_texgens_sheared_domain(tmp_path):
    t = read_tg3(DATA / "plain_g30.tg3")
    write_tg3(t, tmp_path / "out.tg3")
    planes = ET.parse(tmp_path / "out.tg3").getroot().findall("Textile/Domain/Plane")
    normals = [np.array(p.get("Normal").split(), float) if " " in p.get("Normal") and "," not in p.get("Normal")
               else np.array(p.get("Normal").split(","), float) for p in planes]
    # TexGen's own: normals (cos 30, -sin 30, 0) and its opposite for the x sides
    assert np.allclose(normals[0], [np.cos(np.radians(30)), -0.5, 0], atol=1e-12)
    assert np.allclose(normals[1], -normals[0], atol=1e-15)
    back = read_tg3(tmp_path / "out.tg3").cell
    assert back == t.cell


def test_builder_shear_follows_texgen():
    # our plain at 30 degrees has TexGen's lattice and crossings (yarn order aside)
    ours = build("plain", width=1.4, height=0.28, shear=30).cell
    theirs = read_tg3(DATA / "plain_g30.tg3").cell
    assert (ours.lx, ours.shift) == pytest.approx((theirs.lx, theirs.shift), abs=1e-12)
    assert ours.ly == pytest.approx(theirs.ly, abs=1e-12)


def test_shear_zero_builds_the_unsheared_weave():
    a, b = build("satin"), build("satin", shear=0.0)
    assert a.cell == b.cell
    for ya, yb in zip(a.yarns, b.yarns):
        assert np.array_equal(ya.nodes, yb.nodes) and np.array_equal(ya.repeats, yb.repeats)


def test_jamming_is_named():
    # width 1.8 at spacing 2.0: neighbours meet where 2 cos g = 1.8, g = acos 0.9 = 25.84 degrees
    assert jamming_angle([1.8], [2.0]) == pytest.approx(25.841932763, abs=1e-8)
    with pytest.raises(TextileError, match=r"jam at 25\.84 degrees"):
        build("plain", shear=30)
    with pytest.raises(TextileError, match="between -90 and 90"):
        build("plain", width=1.0, shear=90)
    build("plain", width=1.4, shear=45)  # acos 0.7 = 45.57: still fits


def test_command_line_exit_codes(tmp_path):
    # bad input exits 2: a jammed shear, naming the angle; a degenerate lattice in a model file
    run = subprocess.run([sys.executable, "-m", "textile_fenicsx", "solve", "plain", "--shear", "30"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 2 and "jam at 25.84 degrees" in run.stderr, run.stderr[-1000:]
    model = tmp_path / "flat.toml"
    model.write_text('[cell]\nlx = 4.0\nly = 1.0\nshift = 10.0\n[[yarns]]\nnodes = [[0, 0.5, 0.1], [4, 0.5, 0.1]]\n'
                     'section = {type = "ellipse", width = 0.5, height = 0.1}\n')
    run = subprocess.run([sys.executable, "-m", "textile_fenicsx", "solve", str(model)], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 2 and "degenerate lattice" in run.stderr, run.stderr[-1000:]


def test_coupons_and_volume_meshes_are_refused():
    from textile_fenicsx.model.coupon import tile
    from textile_fenicsx.volume.stage import refuse_sheared

    t = build("plain", width=1.4, shear=30)
    with pytest.raises(TextileError, match="not supported yet"):
        tile(t, 2, 1)
    with pytest.raises(TextileError, match="no volume mesh yet"):
        refuse_sheared(t)


# --- the default command ----------------------------------------------------------------------

def _relattice(t: Textile) -> Textile:
    """The same textile described by a1 and a1 + a2 (shift = lx): every sheared path, the same lattice."""
    cell = replace(t.cell, shift=t.cell.shift + t.cell.lx)
    return replace(t, cell=cell, yarns=[replace(y, repeats=cell.repeats) for y in t.yarns])


def test_shear_zero_through_the_sheared_path_equals_the_unsheared():
    # serial only: on 2 ranks this description's corrected thickness came out 1.5e-4 mm off, with
    # the same solve and the same corrected master nodes, and depending on the ranks' timing (an
    # extra collective changed it); open, docs/shear.md
    # shift = lx is the unsheared lattice: the marks, the y sides' pairing, the ghost strip, the
    # images and the crossing orders all take their sheared branch, and the mesh and every
    # number must be the unsheared run's to the solver's round-off (the ghost strip's nodes are
    # numbered otherwise; the interior point stops on moves of 1e-6 mm: measured 2.7e-8 mm apart)
    from textile_fenicsx.api import solve

    plain = build("plain", width=1.4, height=0.28)
    a = solve(plain, seed=0.5, comm=MPI.COMM_WORLD)
    b = solve(_relattice(plain), seed=0.5, comm=MPI.COMM_WORLD)
    ma, mb = a.metrics["after"], b.metrics["after"]
    assert a.verdict["passed"] and b.verdict["passed"]
    assert mb["thickness"] == pytest.approx(ma["thickness"], abs=1e-7)
    assert mb["interpenetration"]["volume"] == pytest.approx(ma["interpenetration"]["volume"], abs=1e-8)
    assert mb["yarn_volume"]["total"] == pytest.approx(ma["yarn_volume"]["total"], rel=1e-7)
    assert a.summary()["dofs"] == b.summary()["dofs"]


@pytest.mark.mpi
def test_default_command_on_sheared_plain_30(tmp_path):
    from textile_fenicsx.api import solve

    comm = MPI.COMM_WORLD
    run = solve(read_tg3(DATA / "plain_g30.tg3"), seed=0.5, comm=comm)
    assert run.verdict["passed"], run.verdict
    after = run.metrics["after"]
    # the idealised plain overlaps 0.33 mm^3; corrected none, 0.56 -> ~0.59 mm thick (as at 0 and 15)
    assert after["interpenetration"]["volume"] < 1e-4
    assert 0.56 < after["thickness"] < 0.62
    assert after["areal"]["shear_angle_deg"] == pytest.approx(30, abs=1e-9)
    assert after["areal"]["cell_area_mm2"] == pytest.approx(16 * np.cos(np.radians(30)), rel=1e-12)
    tmp = comm.bcast(str(tmp_path) if comm.rank == 0 else None)
    out = run.write(Path(tmp) / "out", figures=False)
    if comm.rank == 0:
        back = read_tg3(out / "corrected.tg3")
        assert back.cell.shift == pytest.approx(2.0, abs=1e-9)
        _texgen_reads(out / "corrected.tg3")


def _texgen_reads(path: Path) -> None:
    """TexGen (pytexgen, where its venv is) opens the corrected file with its sheared domain: the
    parallelogram through (-1.5, -0.866) leaning along (2, 3.4641), so at y = 2.4 its x sides are at
    -1.5 + 3.266 tan 30 = 0.386 and 4.386: x = -1 (inside the rectangle) is outside it, x = 3 inside;
    its volume is the cell's area 16 cos 30 times the written z range."""
    python = os.environ.get("TEXTILE_FENICSX_TEXGEN_PYTHON", "/var/cache/textile-fenicsx/pytexgen-venv/bin/python")
    if not os.access(python, os.X_OK):
        pytest.skip(f"no pytexgen at {python} (bench/texgen_env.sh --fenicsx-env makes it): TexGen's read-back "
                    "not checked")
    code = ("import sys; from pytexgen.Core import ReadFromXML, GetTextile, XYZ; ReadFromXML(sys.argv[1]); "
            "t = GetTextile(); d = t.GetDomain(); inside = lambda x: int(d.PointInDomain(XYZ(x, 2.4, 0.3))); "
            "print('RESULT', t.GetNumYarns(), d.GetType(), inside(-1.0), inside(3.0), d.GetVolume())")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    done = subprocess.run([python, "-c", code, str(path)], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    result = [line.split()[1:] for line in done.stdout.splitlines() if line.startswith("RESULT")][-1]
    assert result[:4] == ["4", "CDomainPlanes", "0", "1"], done.stdout[-500:]
    planes = ET.parse(path).getroot().findall("Textile/Domain/Plane")
    z0, z1 = float(planes[4].get("d")), -float(planes[5].get("d"))
    assert float(result[4]) == pytest.approx(16 * np.cos(np.radians(30)) * (z1 - z0), rel=1e-9)
