"""Binder legs fitted into the gap beside them (leg_fit.py, DESIGN.md 7b; issue 27, item 4)."""

import numpy as np
import pytest

from textile_fenicsx.leg_fit import FIT_MARGIN, PROBE_STEPS, fit_legs
from textile_fenicsx.metrics import measure
from textile_fenicsx.sections import Ellipse
from textile_fenicsx.textile import Cell, Textile
from textile_fenicsx.verify import tube
from textile_fenicsx.yarn import ConstantSection, Yarn

L, GAP, H = 2.0, 0.22, 0.3  # cell side, gap between the weft columns, binder thickness [mm]


def binder_through_a_gap(gap: float = GAP) -> Textile:
    """Weft columns along y at x = 0.5 and 1.5, 0.78 mm wide (gaps of 0.22 mm at x = 1 and 2), and a
    binder along x, 0.3 mm thick, over the first and under the second, its legs vertical in the gaps:
    the legs reach 0.04 mm into the wefts on each side, as TexGen's wide-binder orthogonal weaves."""
    reps = [[L, 0, 0], [0, L, 0]]
    weft = ConstantSection(Ellipse(1.0 - gap, 0.3))
    wefts = [Yarn([[x, 0, 0], [x, L / 2, 0], [x, L, 0]], weft, "linear", repeats=reps, name=f"weft {k}")
             for k, x in enumerate((0.5, 1.5))]
    z = 0.15 + H / 2  # on the wefts' tops and under their bottoms
    path = [[0.2, 1, z], [0.5, 1, z], [0.8, 1, z], [0.97, 1, 0.9 * z], [1.0, 1, 0], [1.03, 1, -0.9 * z],
            [1.2, 1, -z], [1.5, 1, -z], [1.8, 1, -z], [1.97, 1, -0.9 * z], [2.0, 1, 0], [2.03, 1, 0.9 * z],
            [2.2, 1, z]]
    binder = Yarn(path, ConstantSection(Ellipse(0.6, H)), "cubic", repeats=reps, name="binder")
    return Textile(Cell(L, L), wefts + [binder], name="binder_through_a_gap")


@pytest.mark.serial
def test_a_leg_thicker_than_its_gap_is_squashed_to_fit_it_with_its_area_kept():
    textile = binder_through_a_gap()
    before = measure(textile)["interpenetration"]
    assert before["volume"] > 1e-3  # the legs reach into the wefts
    fitted = fit_legs(textile, [2])
    assert fitted.yarns[:2] == textile.yarns[:2]  # the neighbours do not move
    after = measure(fitted)["interpenetration"]
    assert after["volume"] < 1e-6 and after["max_depth"] < 1e-3
    # the legs are symmetric in symmetric gaps: not moved sideways, and squashed until the margin
    # is met: thickness GAP - 2 FIT_MARGIN H at mid-height, to the probes' step either way
    binder = fitted.yarns[2]
    k = int(np.argmin(np.abs(binder.nodes[:, 0] - 1.0) + np.abs(binder.nodes[:, 2])))
    assert binder.nodes[k, 0] == pytest.approx(1.0, abs=1e-6)
    section = binder.section_points(np.array([float(k)]), 64)[0]
    step = 1.5 * H / PROBE_STEPS
    assert np.ptp(section[:, 1]) == pytest.approx(GAP - 2 * FIT_MARGIN * H, abs=2 * step)
    # and areas kept: the same volume per length, by the yarn's own surface
    t0, t1 = tube(textile.yarns[2], textile.resolution), tube(binder, fitted.resolution)
    assert t1.per_length / t0.per_length == pytest.approx(1.0, abs=0.01)


@pytest.mark.serial
def test_a_fitted_leg_keeps_the_solves_least_gap_to_its_neighbours():
    # solve --min-gap G: the tet mesh asks for G between yarns, more than the fit's own margin
    # (FIT_MARGIN H = 0.009 mm); the leg is squashed until G is kept on each side, and the probes
    # see a wall up to a step late, so the fit keeps a step more: GAP - 2 (G + step), to a step
    gap = 0.03
    fitted = fit_legs(binder_through_a_gap(), [2], gap=gap).yarns[2]
    k = int(np.argmin(np.abs(fitted.nodes[:, 0] - 1.0) + np.abs(fitted.nodes[:, 2])))
    section = fitted.section_points(np.array([float(k)]), 64)[0]
    step = 1.5 * H / PROBE_STEPS
    thickness = np.ptp(section[:, 1])
    assert thickness <= GAP - 2 * gap
    assert thickness == pytest.approx(GAP - 2 * (gap + step), abs=2 * step)


@pytest.mark.serial
def test_a_leg_that_fits_its_gap_is_left_as_it_is():
    textile = binder_through_a_gap()
    narrow = Yarn(textile.yarns[2].nodes, ConstantSection(Ellipse(0.6, 0.15)), "cubic",
                  repeats=textile.yarns[2].repeats, name="binder")
    textile = Textile(textile.cell, textile.yarns[:2] + [narrow], name="narrow_binder")
    assert fit_legs(textile, [2]).yarns[2] is narrow


@pytest.mark.serial
def test_a_leg_that_cannot_fit_its_gap_is_left_as_it_is_and_named(caplog):
    # a 0.1 mm gap for the 0.3 mm binder: squashed to FIT_LEAST (0.4) it would still be 0.12 mm
    textile = binder_through_a_gap(gap=0.1)
    with caplog.at_level("WARNING", logger="textile_fenicsx.leg_fit"):
        fitted = fit_legs(textile, [2])
    assert fitted.yarns[2] is textile.yarns[2]
    assert "binder's leg at (" in caplog.text and "cannot be fitted into the gap beside it" in caplog.text
