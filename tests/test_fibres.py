"""Fibre data as TexGen writes it (units beside values), the intra-yarn and cell fibre fractions."""

import json
import math

import numpy as np
import pytest

from textile_fenicsx.common.errors import FormatError
from textile_fenicsx.io.config import load_model, save_model, textile_from_dict
from textile_fenicsx.io.tg3 import read_tg3
from textile_fenicsx.io.tg3_write import write_tg3
from textile_fenicsx.model import fibres
from textile_fenicsx.model.metrics import yarn_fibre_fractions

pytestmark = pytest.mark.serial


def test_yarn_fibre_data_in_texgen_units_is_converted(reference_dir):
    # reference/models/yarn_fibres.api.txt: 7e-06 m, 0.46 mm^2, 1.78 g/cm^3, 800 tex, 12000 fibres.
    # The 7 um fibre in metres was refused before ("fibre diameter must be at least 0.0001 mm").
    f = read_tg3(reference_dir / "models" / "yarn_fibres.tg3").yarns[0].fibres
    assert (f.count, f.diameter, f.area, f.density, f.linear_density) == pytest.approx((12000, 0.007, 0.46, 1.78, 800))
    assert f.fibre_area() == 0.46  # a fibre area given comes first (TexGen's order)


def test_textile_fibre_data_is_every_yarns_and_gives_texgens_fraction(reference_dir):
    # reference/models/satin4_fibres.api.txt: on the textile 1200 tex at 2550 kg/m^3, 17e-06 m fibres.
    t = read_tg3(reference_dir / "models" / "satin4_fibres.tg3")
    assert all(y.fibres == t.yarns[0].fibres for y in t.yarns)
    area = 1200 / (1000 * 2.55)  # tex / rho [mm^2]: linear density before fibres x diameter
    assert t.yarns[0].fibres.fibre_area() == pytest.approx(area, rel=1e-12)
    vf, source = yarn_fibre_fractions(t)
    exact = area / (math.pi / 4 * 2.5 * 0.35)  # the 2.5 x 0.35 mm ellipse
    assert source == "model" and vf == pytest.approx([exact] * 8, rel=1e-5)
    # TexGen's own CYarn::GetFibreYarnVolumeFraction (pytexgen 1.2.1) gives 0.6876078 for every yarn:
    # the same fibre area over its 40-point polygon, which holds sin(a)/a of the ellipse (a = 2 pi/40)
    a = 2 * math.pi / 40
    assert 0.6876078 * math.sin(a) / a == pytest.approx(exact, rel=1e-4)  # 2.4e-5 apart: its mesh volume


def test_texgens_order_of_fibre_data():
    both = fibres.Fibres(count=2000, diameter=0.017, linear_density=1200, density=2.55)
    assert both.fibre_area() == pytest.approx(1200 / 2550)  # pytexgen: 0.470588 with both given
    assert fibres.Fibres(count=2000, diameter=0.017).fibre_area() == pytest.approx(2000 * math.pi * 0.017**2 / 4)
    assert fibres.Fibres(density=2.55).fibre_area() is None


def test_fibre_data_round_trips_through_tg3_and_json(reference_dir, tmp_path):
    t = read_tg3(reference_dir / "models" / "yarn_fibres.tg3")
    write_tg3(t, tmp_path / "again.tg3")
    assert read_tg3(tmp_path / "again.tg3").yarns[0].fibres == t.yarns[0].fibres
    save_model(t, tmp_path / "again.json")
    assert load_model(tmp_path / "again.json").yarns[0].fibres == t.yarns[0].fibres


def test_model_format_takes_fibre_data_for_every_yarn():
    d = {"weave": {"type": "plain", "spacing": 2.0, "width": 1.8, "height": 0.3},
         "fibres": {"linear_density": 600, "density": 2.55}}
    t = textile_from_dict(d)
    assert all(y.fibres.fibre_area() == pytest.approx(600 / 2550) for y in t.yarns)
    with pytest.raises(FormatError, match=r"model\.fibres: unknown key\(s\) \['diametre'\]"):
        textile_from_dict({**d, "fibres": {"diametre": 0.007}})


def test_bad_fibre_units_name_the_attribute(reference_dir, tmp_path):
    text = (reference_dir / "models" / "yarn_fibres.tg3").read_text()
    bad = tmp_path / "bad.tg3"
    bad.write_text(text.replace('FibreDiameterUnits="m"', 'FibreDiameterUnits="furlong"'))
    with pytest.raises(FormatError, match=r"Yarn 0 FibreDiameterUnits: unknown unit 'furlong'"):
        read_tg3(bad)
    bad.write_text(text.replace('FibreDiameterUnits="m"', ""))
    with pytest.raises(FormatError, match=r"FibreDiameterValue=.* has no FibreDiameterUnits"):
        read_tg3(bad)
    bad.write_text(text.replace('FibreDensityUnits="g/cm^3"', 'FibreDensityUnits="kg/m^3"'))
    with pytest.raises(FormatError, match=r"fibre density must be from 0.1 to 25 g/cm\^3, got 0.00178"):
        read_tg3(bad)


def test_a_model_without_fibre_data_gets_the_stated_default(reference_dir, caplog):
    from textile_fenicsx.model import metrics

    metrics._WARNED.clear()  # the warning is given once per model and process
    t = read_tg3(reference_dir / "models" / "plain.tg3")
    vf, source = yarn_fibre_fractions(t)
    assert source == "default" and np.all(np.array(vf) == fibres.DEFAULT_YARN_VF)
    assert "no fibre data" in caplog.text and "0.65" in caplog.text


def test_metrics_report_the_cell_fibre_fraction(reference_dir):
    from textile_fenicsx.model.metrics import measure

    t = read_tg3(reference_dir / "models" / "satin4_fibres.tg3")
    m = measure(t, n=100)
    vf = np.array(m["yarn_vf"])
    expected = float(np.dot(vf, m["yarn_volume"]["per_yarn"]) / (t.cell.area * m["thickness"]))
    assert m["vf"] == pytest.approx(expected, rel=1e-12) and 0 < m["vf"] < 0.907
    assert json.dumps(m)  # JSON-ready
