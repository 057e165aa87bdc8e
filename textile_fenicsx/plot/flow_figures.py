"""The picture of a cell's flow, flow.png (matplotlib; the field sampled by pyvista, no X server, as
in volume_figures.py): a row per load case (a mean pressure gradient of 1 Pa/mm along x, y, z), its
velocity magnitude on a plan cut z = const and the upright cuts y = const and x = const, each
through the plane where that load case's flow is fastest on average (the channels), with arrows of
the velocity in the cut's plane; axes in mm (z drawn Z_STRETCH times taller on the upright cuts of
a thin cell, which are then stacked beside the plan; side by side with it otherwise) and a colour
bar per load case in mm/s per Pa/mm (the velocity is linear in the gradient).

It reads flow.vtu (flow/files.py: point data velocity_x, velocity_y, velocity_z at the nodes of
the P2 velocity, which VTK's quadratic cells interpolate as the elements do), so that this module
needs nothing of the flow stage.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from textile_fenicsx.common.files import naming
from textile_fenicsx.plot.volume_figures import Z_STRETCH

__all__ = ["fastest_level", "flow_cuts", "sample_cut"]

CASES = ("x", "y", "z")
# each row's cuts: (the plane's normal, the axes drawn across and up)
CUTS = ((2, 0, 1), (1, 0, 2), (0, 1, 2))
# samples along the cell's longest side; slabs in which the flow's mean speed is compared
PIXELS = 160
SLABS = 16
ARROWS = 18  # along the longest side


def fastest_level(coordinate: np.ndarray, speed: np.ndarray, lo: float, hi: float, slabs: int = SLABS) -> float:
    """The level in [lo, hi] of the slab (of `slabs` equal ones) in which the nodes' mean speed is
    largest: the mean coordinate of its nodes (the middle where all are equally slow)."""
    edges = np.linspace(lo, hi, slabs + 1)
    which = np.clip(np.searchsorted(edges, coordinate, side="right") - 1, 0, slabs - 1)
    count = np.bincount(which, minlength=slabs)
    mean = np.bincount(which, weights=speed, minlength=slabs) / np.maximum(count, 1)
    if not np.any(mean > 0):
        return 0.5 * (lo + hi)
    best = int(np.argmax(np.where(count > 0, mean, -1.0)))
    return float(coordinate[which == best].mean())


def sample_cut(grid: Any, name: str, normal: int, level: float, across: int, up: int, step: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The point data `name` (N, 3) of a pyvista grid sampled (VTK's probe: each cell's own
    interpolation) at the centres of square pixels of side `step` [mm] over the plane x_normal =
    level: (values (rows, columns, 3), NaN outside the cells; the pixels' centres across and up)."""
    import pyvista

    bounds = np.asarray(grid.bounds).reshape(3, 2)
    a = _centres(bounds[across, 0], bounds[across, 1], step)
    b = _centres(bounds[up, 0], bounds[up, 1], step)
    points = np.zeros((len(b), len(a), 3))
    points[..., across], points[..., up] = np.meshgrid(a, b)
    points[..., normal] = level
    probe = pyvista.PolyData(points.reshape(-1, 3)).sample(grid)
    values = np.asarray(probe.point_data[name], float).reshape(len(b), len(a), -1)
    values[np.asarray(probe.point_data["vtkValidPointMask"]).reshape(len(b), len(a)) == 0] = np.nan
    return values, a, b


def _centres(lo: float, hi: float, step: float) -> np.ndarray:
    """The centres of the fewest (at least 2) equal intervals of [lo, hi] no longer than step."""
    n = max(int(np.ceil((hi - lo) / step)), 2)
    return lo + (np.arange(n) + 0.5) * (hi - lo) / n


def _panel(ax: Any, values: np.ndarray, a: np.ndarray, b: np.ndarray, normal: int, across: int, up: int,
           level: float, vmax: float, case: int, stretch: float) -> Any:
    """One cut on ax: the speed as an image, arrows of the velocity in the plane, axes in mm (z
    drawn `stretch` times taller); case: the load case's gradient direction (0, 1, 2)."""
    import matplotlib.pyplot as plt

    axis = "xyz"
    speed = np.linalg.norm(values, axis=2)
    da, db = a[1] - a[0], b[1] - b[0]
    cmap = plt.get_cmap("viridis").with_extremes(bad="white")
    image = ax.imshow(speed, origin="lower", extent=(a[0] - da / 2, a[-1] + da / 2, b[0] - db / 2, b[-1] + db / 2),
                      cmap=cmap, vmin=0.0, vmax=vmax, interpolation="bilinear",
                      aspect=stretch if up == 2 else 1.0)
    every = max(1, int(round(max(len(a), len(b)) / ARROWS)))
    rows, columns = np.arange(every // 2, len(b), every), np.arange(every // 2, len(a), every)
    sub = values[np.ix_(rows, columns)]
    shown = np.linalg.norm(sub[..., [across, up]], axis=2) > 0.05 * vmax
    A, B = np.meshgrid(a[columns], b[rows])
    if np.any(shown):  # along the flow as drawn (z stretched too), as long as it is fast: vmax 0.9 of their spacing
        ax.quiver(A[shown], B[shown], sub[..., across][shown], sub[..., up][shown], color="white", angles="xy",
                  scale_units="width", scale=vmax * len(a) / (0.9 * every), width=0.004, headwidth=3.5, alpha=0.85)
    ax.set_xlabel(f"{axis[across]} [mm]", fontsize=9)
    ax.set_ylabel(f"{axis[up]} [mm]" + (f", drawn x{stretch:g}" if up == 2 and stretch != 1 else ""), fontsize=9)
    where = " (the centre)" if normal == case else " (fastest mean flow)"
    ax.set_title(f"cut {axis[normal]} = {np.round(level, 6) + 0.0:.4g} mm{where}", fontsize=9)
    ax.tick_params(labelsize=8)
    return image


def flow_cuts(vtu: Path, path: Path, mu: float = 1.0, K: np.ndarray | None = None) -> Path:
    """flow.png from flow.vtu (module docstring); mu: the viscosity [Pa s] the velocities were
    solved with, K: the cell's permeability [mm^2] for the titles (or None)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pyvista

    grid = pyvista.read(vtu)
    bounds = np.asarray(grid.bounds).reshape(3, 2)
    size = bounds[:, 1] - bounds[:, 0]
    step = size.max() / PIXELS
    stretch = Z_STRETCH if Z_STRETCH * size[2] <= size[:2].max() else 1.0
    stacked = 2 * stretch * size[2] <= size[1]  # the upright cuts one above the other beside the plan
    inch = (4.2 if stacked else 3.6) / size[:2].max()  # per mm: the plan's larger side 4.2 or 3.6 inches
    if stacked:
        width, row = inch * (size[0] + size[:2].max()) + 2.6, max(inch * size[1], 2 * inch * stretch * size[2] + 1.0)
    else:
        width, row = inch * (2 * size[0] + size[1]) + 3.4, inch * max(size[1], stretch * size[2]) + 0.2
    fig = plt.figure(figsize=(width, 3 * (row + 1.1)), layout="constrained")
    fig.get_layout_engine().set(h_pad=0.08)  # the rows' titles clear of the cuts' own
    for k, (case, sub) in enumerate(zip(CASES, fig.subfigures(3, 1, hspace=0.04))):
        velocity = np.asarray(grid.point_data[f"velocity_{case}"])
        speed = np.linalg.norm(velocity, axis=1)
        cuts = []
        for normal, across, up in CUTS:
            level = (fastest_level(grid.points[:, normal], speed, bounds[normal, 0], bounds[normal, 1])
                     if normal != k else float(bounds[normal].mean()))
            cuts.append((sample_cut(grid, f"velocity_{case}", normal, level, across, up, step), level))
        vmax = max(float(np.nanmax(np.linalg.norm(c[0][0], axis=2), initial=0.0)) for c in cuts) or 1.0
        if stacked:
            layout = sub.add_gridspec(2, 2, width_ratios=(size[0], size[:2].max()))
            axes = [sub.add_subplot(layout[:, 0]), sub.add_subplot(layout[0, 1]), sub.add_subplot(layout[1, 1])]
        else:
            layout = sub.add_gridspec(1, 3, width_ratios=(size[0], size[0], size[1]))
            axes = [sub.add_subplot(layout[0, i]) for i in range(3)]
        image = None
        for ax, ((values, a, b), level), (normal, across, up) in zip(axes, cuts, CUTS):
            image = _panel(ax, values, a, b, normal, across, up, level, vmax, k, stretch)
        bar = sub.colorbar(image, ax=axes, shrink=0.85, aspect=30)
        bar.set_label("|u| [mm/s] per Pa/mm of mean pressure gradient", fontsize=9)
        bar.ax.tick_params(labelsize=8)
        title = f"load case {case}: mean pressure gradient 1 Pa/mm along -{case} (flow along +{case}), mu = {mu:g} Pa s"
        if K is not None:
            title += f"; K{case}{case} = {K[k, k] * 1e-6:.3g} m^2"
        sub.suptitle(title, fontsize=11, weight="bold")
    with naming(path):
        fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
