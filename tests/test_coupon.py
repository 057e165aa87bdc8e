"""Coupons: n x m repeats of a unit cell as one periodic problem (issue 7)."""

import numpy as np
import pytest
from mpi4py import MPI

from textile_fenicsx.config import load_model
from textile_fenicsx.coupon import tile
from textile_fenicsx.errors import TextileError
from textile_fenicsx.meshes.projected import MeshOptions
from textile_fenicsx.metrics import measure
from textile_fenicsx.pipeline import run
from textile_fenicsx.weaves import build


@pytest.mark.serial
@pytest.mark.parametrize("name", ["satin4", "orthogonal", "twill"])
def test_tiled_model_is_the_unit_cell_repeated(name, reference_dir):
    # 2 x 2 repeats sampled on a 200-ray grid hit the same points as the unit cell on a 100-ray
    # grid: volumes and interpenetration x4, thickness and crimp equal (to the stations' resampling)
    t = load_model(reference_dir / "models" / "satin4.tg3") if name == "satin4" else build(name)
    big = tile(t, 2, 2)
    a, b = measure(t, 100), measure(big, 200)
    assert b["yarn_volume"]["total"] == pytest.approx(4 * a["yarn_volume"]["total"], rel=1e-6)
    assert b["interpenetration"]["volume"] == pytest.approx(4 * a["interpenetration"]["volume"], rel=1e-6)
    assert b["thickness"] == pytest.approx(a["thickness"], rel=1e-6)
    assert sorted(np.round(b["crimp"], 6)) == sorted(np.round(list(a["crimp"]) * 2, 6))  # each yarn continued, 2 copies
    # a yarn along x of the unit cell becomes 2 copies of twice its length in a 2 x 2 coupon
    assert len(big.yarns) == 2 * len(t.yarns)


@pytest.mark.serial
def test_coupon_yarn_counts_follow_the_periods():
    t = build("plain")  # 2 warps along x, 2 wefts along y
    big = tile(t, 3, 2)
    along_x = [y for y in big.yarns if abs(y.period[1]) < 1e-9]
    along_y = [y for y in big.yarns if abs(y.period[0]) < 1e-9]
    assert len(along_x) == 2 * 2 and all(y.period[0] == pytest.approx(3 * t.cell.lx) for y in along_x)
    assert len(along_y) == 2 * 3 and all(y.period[1] == pytest.approx(2 * t.cell.ly) for y in along_y)
    with pytest.raises(TextileError, match="coupon repeats ny must be a whole number >= 1"):
        tile(t, 2, 1.5)


@pytest.mark.mpi
def test_coupon_solution_repeats_the_unit_cell():
    # every repeat of a periodic coupon sees the same neighbours: the solution is the unit cell's
    # (up to the different meshes: the largest |w| agrees to 2 %, the penetration to 5 %)
    t = build("plain", spacing=2.0, width=1.8, height=0.3, thickness=0.6)
    unit = run(t, MeshOptions(0.5), log=None).summary()
    coupon = run(tile(t, 2, 1), MeshOptions(0.5), log=None)
    s = coupon.summary()
    assert coupon.solution.converged
    assert s["max_abs_w"] == pytest.approx(unit["max_abs_w"], rel=0.02)
    assert s["max_penetration_nodal"] == pytest.approx(unit["max_penetration_nodal"], rel=0.05)
    assert 1.6 * unit["dofs"] < s["dofs"] < 2.4 * unit["dofs"]  # two cells, meshed anew
