"""Loops taken out of master nodes that run back in plan (loops.py; issue 27)."""

import numpy as np
import pytest
from mpi4py import MPI

from conftest import REPO
from textile_fenicsx.correction.legs import plate_model
from textile_fenicsx.correction.loops import unlooped, unlooped_yarn
from textile_fenicsx.io.config import load_model
from textile_fenicsx.model.sections import Ellipse
from textile_fenicsx.model.yarn import NodeSections, Yarn
from textile_fenicsx.pipeline.stages import Settings, run
from textile_fenicsx.plate.mesh.projected import MeshOptions

FABRICS = REPO / "reference" / "fabrics"


def along(yarn: Yarn) -> np.ndarray:
    """Each master node's position along the yarn's direction in plan [mm]."""
    d = yarn.period[:2] / np.linalg.norm(yarn.period[:2])
    return yarn.nodes[:, :2] @ d


@pytest.mark.serial
def test_a_layer_to_layer_binders_crossed_nodes_become_one_node_at_its_column(caplog):
    # TexGen writes the wide binder's leg nodes past each other, x 5.64 then 5.56 mm, both at its
    # height there (z 1.45): one node at their mean, 5.60, the weft column's gap; the path is then
    # 2 x (0.08 + 0.08) mm shorter less what the Bezier's turns took, and runs forward everywhere
    t = load_model(FABRICS / "l2l_w2f3_b3_0011_binder1.0x0.3.tg3")
    with caplog.at_level("INFO", logger="textile_fenicsx.correction.loops"):
        u, which = unlooped(t)
    assert which == (2, 3, 4, 7, 8, 9)
    assert "loops: yarn 9 runs back in plan: master nodes 10, 11 step 0.08 mm back: one node at (5.6, 9.4, 1.45) mm" \
        in caplog.text
    for i, (y0, y) in enumerate(zip(t.yarns, u.yarns)):
        if i not in which:
            assert y is y0
            continue
        assert len(y.nodes) == len(y0.nodes) - 1
        assert np.all(np.diff(along(y)) > 0)
        old = np.concatenate([y0.nodes + k * y0.period for k in (-1, 0, 1)])
        new = [p for p in y.nodes[:-1] if np.min(np.linalg.norm(old - p, axis=1)) > 1e-9]
        column = 5.6 if i >= 7 else 11.2
        assert len(new) == 1 and new[0][0] == pytest.approx(column, abs=1e-12)
        assert new[0][2] == pytest.approx(y0.nodes[np.argmin(np.abs(y0.nodes[:, 0] - column - 0.04)), 2])
        assert np.allclose(y.nodes[-1] - y.nodes[0], y0.period)  # still periodic, the same period
        s = np.linspace(0, y.n_segments, 4000)
        _, tan = y.centreline(s)
        assert np.all(tan[:, 0] > 0)  # no longer turns back
        assert y.length() < y0.length() - 0.1
    # the plates are made from it: no yarn is cut into crowns now (its legs are 52 degrees steep)
    split = plate_model(t, 0.5)
    assert split.unlooped == which and not split.any and split.textile is not t
    assert split.binders == list(which)


@pytest.mark.serial
def test_an_orthogonal_binders_leg_leaning_back_is_left_as_it_is():
    # the orthogonal weave's crossed pair is at two heights (x 5.64, z 0.15 then x 5.56, z 1.45): a
    # vertical leg leaning back 0.08 mm, which is a leg anyway (legs.py); it is not moved
    t = load_model(FABRICS / "ortho_w2f3_binder1.0x0.3.tg3")
    binder = t.yarns[2]
    assert np.any(np.diff(along(binder)) < -0.07)  # it does lean back
    assert unlooped(t) == (t, ())
    assert plate_model(t, 0.5).textile is t


@pytest.mark.serial
def test_models_without_loops_are_left_as_they_are():
    for name in ("l2l_w2f3_b3_0011", "ortho_w2f3", "angleinterlock_w2f3_y6"):
        t = load_model(FABRICS / f"{name}.tg3")
        assert unlooped(t) == (t, ())
    t = load_model(REPO / "reference" / "models" / "satin4.tg3")
    assert unlooped(t) == (t, ())


@pytest.mark.serial
def test_node_sections_follow_their_nodes_when_a_loop_is_merged():
    # an open yarn whose nodes 2 and 3 cross (x 2.1, 1.9) at one height: one node at x 2.0 with
    # node 2's section; the mid-section of segment 3 -> 4 (now 2 -> 3) stays, that of the merged
    # segment 2 -> 3 goes
    sec = [Ellipse(1.0 + 0.1 * k, 0.2) for k in range(6)]
    nodes = [[0, 0, 0], [1, 0, 0.1], [2.1, 0, 0.2], [1.9, 0, 0.2], [3, 0, 0.3], [4, 0, 0.3]]
    mid = ((2, 0.5, Ellipse(3.0, 0.2)), (3, 0.5, Ellipse(4.0, 0.2)))
    y = Yarn(nodes, NodeSections(tuple(sec), mid=mid), periodic=False, ups=np.tile([0, 0, 1.0], (6, 1)))
    u, moved = unlooped_yarn(y)
    assert len(moved) == 1 and "2, 3" in moved[0]
    assert np.allclose(u.nodes[:, 0], [0, 1, 2, 3, 4]) and np.allclose(u.nodes[2], [2, 0, 0.2])
    assert u.section.at_nodes == (sec[0], sec[1], sec[2], sec[4], sec[5])
    assert [(k, t, s.width) for k, t, s in u.section.mid] == [(2, 0.5, 4.0)]
    assert u.ups.shape == (5, 3)


@pytest.mark.mpi
@pytest.mark.slow
def test_the_wide_binder_layer_to_layer_weave_passes_its_check_without_its_loops():
    # with its loops the corrected binders folded 5.95 % of their volume (limit 0.1 %) and their
    # sections crossed themselves at station 41 (docs/sweep.md); without them, as whole plates with
    # their bends opened (bend_fit.py), they fold at most 0.04 % and keep their volume per length
    t = load_model(FABRICS / "l2l_w2f3_b3_0011_binder1.0x0.3.tg3")
    r = run(t, Settings(MeshOptions(0.5)), comm=MPI.COMM_WORLD)
    assert r.converged, r.solution.reason
    assert r.verdict["passed"], r.verdict["failures"]
    m = r.metrics
    assert max(m["yarn_folded_fraction"]) < 1e-3
    assert max(abs(c) for c in m["yarn_surface_volume_per_length_change"]) < 0.01
    assert m["after"]["thickness"] <= m["before"]["thickness"] + 0.003  # the mould, 2.2 mm, holds it
    nodes = np.concatenate([y.nodes for y in r.corrected.yarns])
    assert all(np.array_equal(nodes, other) for other in MPI.COMM_WORLD.allgather(nodes))


@pytest.mark.serial
def test_a_loop_across_a_periodic_yarns_first_node_is_merged_with_its_sections():
    # period 4 mm: node 3 (x 4.1) lies past node 4, node 0 a period on (x -0.1 + 4 = 3.9), both at
    # z 0.2: the walk across the wrap merges them into one node at x 4.0 (0.0 in the first period)
    sec = [Ellipse(1.0 + 0.1 * k, 0.2) for k in range(5)]
    nodes = [[-0.1, 0, 0.2], [1, 0, 0.1], [2.5, 0, 0], [4.1, 0, 0.2], [3.9, 0, 0.2]]
    mid = ((0, 0.5, Ellipse(3.0, 0.2)), (2, 0.5, Ellipse(4.0, 0.2)), (3, 0.5, Ellipse(5.0, 0.2)))
    y = Yarn(nodes, NodeSections(tuple(sec[:4]) + (sec[0],), mid=mid), periodic=True)
    u, moved = unlooped_yarn(y)
    assert len(moved) == 1 and "3, 0" in moved[0]
    assert np.allclose(u.period, y.period)
    assert np.all(np.diff(along(u)) > 0) and len(u.nodes) == 4
    x = np.mod(u.nodes[:-1, 0], 4.0)
    assert np.allclose(np.sort(x), [0.0, 1.0, 2.5])
    # the merged node keeps node 3's section; segments 0 -> 1 and 2 -> 3 keep their mid-sections,
    # the merged segment 3 -> 4 loses its own
    merged = int(np.argmin(np.abs(x - 0.0)))
    assert u.section.at_nodes[merged] is sec[3]
    assert u.section.at_nodes[-1] is u.section.at_nodes[0]
    widths = sorted(s.width for _, _, s in u.section.mid)
    assert widths == [3.0, 4.0]
    for k, _, s in u.section.mid:  # each on the segment between the nodes it was between
        a, b = u.nodes[k], u.nodes[k + 1]
        assert (s.width == 3.0) == (np.mod(a[0], 4.0) < 1e-9 and b[0] - a[0] == pytest.approx(1.0))
