"""The figures a user sees (plotting.py): every plotter gives its picture axes in mm and a legend or
a scalar bar, checked on the pyvista Plotter or matplotlib Figure before it is drawn; and the
one-line reprs of the objects a user holds."""

from contextlib import contextmanager

import numpy as np
import pytest

from textile_fenicsx.model.coupon import tile
from textile_fenicsx.model.weaves import build
from textile_fenicsx.pipeline.outputs import cut_lines
from textile_fenicsx.plot import plotting


def axis_rulers(view) -> list[str]:
    """Titles of the 2D axes (rulers) among the plotter's actors."""
    import vtk

    actors = view.renderer.GetActors2D()
    actors.InitTraversal()
    titles = []
    for _ in range(actors.GetNumberOfItems()):
        actor = actors.GetNextActor2D()
        if isinstance(actor, vtk.vtkAxisActor2D):
            titles.append(actor.GetTitle())
    return titles


@contextmanager
def plotter(make, *args, **kwargs):
    """The Plotter a plotting function makes (off screen), closed after the block."""
    with plotting.offscreen():
        made = make(*args, **kwargs)
        try:
            yield made
        finally:
            made.close()


def assert_mm_axes(view, z_title: str) -> None:
    cube = view.renderer.cube_axes_actor
    assert cube is not None, "no bounds axes"
    assert (cube.GetXTitle(), cube.GetYTitle()) == ("x [mm]", "y [mm]")
    assert any(t.startswith(z_title) for t in axis_rulers(view)), axis_rulers(view)


@pytest.mark.serial
def test_the_3d_view_has_axes_in_mm_and_names_the_yarns():
    textile = build("plain")
    with plotter(plotting.textile_plotter, textile, None, "plain") as view:
        assert_mm_axes(view, "z [mm]")
        legend = view.legend
        assert legend is not None and legend.GetNumberOfEntries() == len(textile.yarns)
        assert [legend.GetEntryString(i) for i in range(len(textile.yarns))] == [y.name for y in textile.yarns]


@pytest.mark.serial
def test_a_coupon_with_many_yarns_gets_a_scalar_bar_instead():
    coupon = tile(build("plain"), 8, 8)  # 32 yarns: past the legend's limit
    assert len(coupon.yarns) > plotting.MAX_LEGEND
    with plotter(plotting.textile_plotter, coupon, None) as view:
        assert "yarn index" in view.scalar_bars
        assert_mm_axes(view, "z [mm]")


@pytest.mark.serial
def test_the_height_field_has_its_scalar_bar_and_axes():
    x, y = np.meshgrid(np.linspace(0, 2, 5), np.linspace(0, 1, 4), indexing="ij")
    points = np.column_stack((x.ravel(), y.ravel(), np.zeros(x.size)))
    a = np.arange(20).reshape(5, 4)
    triangles = np.vstack([np.column_stack((a[:-1, :-1].ravel(), a[1:, :-1].ravel(), a[1:, 1:].ravel())),
                           np.column_stack((a[:-1, :-1].ravel(), a[1:, 1:].ravel(), a[:-1, 1:].ravel()))])
    with plotter(plotting.height_field_plotter, points, triangles, 0.1 * points[:, 0], "w", "a plate",
                 warp=5.0) as view:
        assert "w [mm]" in view.scalar_bars
        assert_mm_axes(view, "w [mm], drawn x5")


@pytest.mark.serial
def test_the_cross_sections_have_labelled_axes_and_a_legend():
    import matplotlib.pyplot as plt

    textile = build("plain")
    fig = plotting.cross_sections_figure(textile, textile, cut_lines(textile), n=100)
    try:
        axes = np.array(fig.axes).reshape(-1, 2)
        assert all(ax.get_xlabel() == "distance along the cut [mm]" for ax in axes.ravel())
        assert all(ax.get_ylabel() == "z [mm]" for ax in axes[:, 0])
        (legend,) = fig.legends
        assert [t.get_text() for t in legend.get_texts()] == [y.name for y in textile.yarns]
    finally:
        plt.close(fig)


@pytest.mark.serial
@pytest.mark.parametrize("sets", [3, plotting.MAX_LEGEND + 1])
def test_the_mesh_picture_has_labelled_axes_and_names_the_covering_sets(sets):
    import matplotlib.pyplot as plt

    x = np.vstack([[[k, 0.0], [k + 1.0, 0.0], [k, 1.0]] for k in range(sets)])  # one triangle per set
    coverage = {t + 1: tuple(range(t % 3)) for t in range(sets)}
    fig = plotting.projected_mesh_figure(x, np.arange(1, sets + 1), coverage, "cells")
    try:
        ax = fig.axes[0]
        assert (ax.get_xlabel(), ax.get_ylabel()) == ("x [mm]", "y [mm]")
        if sets <= plotting.MAX_LEGEND:
            assert len(ax.get_legend().get_texts()) == sets
        else:  # coloured by how many yarns cover each cell: a colour bar
            assert fig.axes[1].get_ylabel() == "yarns over the cell"
    finally:
        plt.close(fig)


@pytest.mark.serial
def test_the_model_objects_print_on_one_line():
    textile = build("crowfoot_satin")
    for thing in (textile, textile.yarns[0], tile(textile, 2, 2)):
        text = repr(thing)
        assert "\n" not in text and len(text) < 200, text
    assert repr(textile).startswith("<Textile 'crowfoot_satin': cell ")
    assert f"{len(textile.yarns)} yarns" in repr(textile)
    assert repr(textile.yarns[0]).startswith(f"<Yarn {textile.yarns[0].name!r}: ")
