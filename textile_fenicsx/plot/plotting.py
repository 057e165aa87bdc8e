"""Off-screen pictures with pyvista.

Debian's VTK renders only through X11, and segfaults rather than raising without a display
(DESIGN.md section 10). `offscreen()` starts a private Xvfb when no DISPLAY is set (Xvfb picks a
free display number itself, so concurrent runs do not collide) and stops it afterwards.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import dolfinx


@contextlib.contextmanager
def offscreen():
    """Provide an X display for VTK for the duration of the block."""
    if os.environ.get("DISPLAY"):
        yield os.environ["DISPLAY"]
        return
    if shutil.which("Xvfb") is None:
        raise RuntimeError("pictures need an X server: install Xvfb (Debian package xvfb) or set DISPLAY")
    read, write = os.pipe()
    proc = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write), "-screen", "0", "1600x1200x24", "-nolisten", "tcp"],
        pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    os.close(write)
    try:
        with os.fdopen(read) as f:
            number = f.readline().strip()
        if not number:
            raise RuntimeError("Xvfb did not start (no display number reported)")
        os.environ["DISPLAY"] = f":{number}"
        yield os.environ["DISPLAY"]
    finally:
        os.environ.pop("DISPLAY", None)
        proc.terminate()
        proc.wait(timeout=10)


def gather_p1_surface(u: dolfinx.fem.Function, root: int = 0):
    """Gather the owned cells of a scalar field's mesh, with u at their vertices, on rank `root`.

    Returns (points (N, 3), triangles (M, 3), values (N,)) on `root` and None elsewhere. Vertices on
    rank boundaries appear once per rank: fine for pictures, not for computation.
    """
    import dolfinx

    msh = u.function_space.mesh
    tdim = msh.topology.dim
    n_owned = msh.topology.index_map(tdim).size_local
    x_dofs = msh.geometry.dofmap[:n_owned, :3]
    local_nodes, tri = np.unique(x_dofs, return_inverse=True)
    points = msh.geometry.x[local_nodes]
    values = np.empty(len(local_nodes))
    # Evaluate u at the mesh nodes through a P1 interpolant (exact at vertices for Lagrange spaces).
    V1 = dolfinx.fem.functionspace(msh, ("Lagrange", 1))
    u1 = dolfinx.fem.Function(V1)
    u1.interpolate(u)
    # P1 dofs of a degree-1 mesh coincide with geometry nodes cell by cell.
    cell_dofs = V1.dofmap.list[:n_owned]
    values[tri.reshape(-1, 3)] = u1.x.array[cell_dofs]
    parts = msh.comm.gather((points, tri.reshape(-1, 3), values), root=root)
    if msh.comm.rank != root:
        return None
    offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    return (np.vstack([p[0] for p in parts]),
            np.vstack([p[1] + o for p, o in zip(parts, offsets)]),
            np.concatenate([p[2] for p in parts]))


# At most this many named entries in a legend; more yarns (a coupon's) get a scalar bar of the index.
MAX_LEGEND = 30
# The 3D views stretch z by this much (fabrics are thin); the axes' labels show true millimetres.
Z_STRETCH = 2.0


def yarn_colours(n: int) -> np.ndarray:
    """RGB colours (n, 3) in [0, 1] of yarns 0..n-1, the same in every figure: matplotlib's tab20,
    tab20b and tab20c one after the other (60 colours, then again)."""
    from matplotlib import colormaps

    palette = [colormaps[name](k)[:3] for name in ("tab20", "tab20b", "tab20c") for k in range(20)]
    return np.array([palette[i % len(palette)] for i in range(n)])


def mm_axes(plotter, bounds, z_stretch: float = 1.0, z_name: str = "z") -> None:
    """Axes in mm on a 3D view: the scene's x and y edges with ticks (VTK's cube axes, which label
    the scene's bounds on every render), and a ruler up one vertical edge for z (the cube axes leave
    a thin z edge without labels) from z0 to z1 [mm], drawn `z_stretch` times taller; `bounds`
    (x0, x1, y0, y1, z0, z1) place the ruler."""
    x0, x1, y0, y1, z0, z1 = bounds
    plotter.show_bounds(xtitle="x [mm]", ytitle="y [mm]", ztitle="", show_zaxis=False, show_zlabels=False,
                        location="outer", ticks="outside", n_xlabels=4, n_ylabels=4, font_size=10, fmt="%.3g")
    ztitle = f"{z_name} [mm]" + ("" if z_stretch == 1 else f", drawn x{z_stretch:g}")
    # drawn downwards, so that its labels stand left of the edge, off the yarns
    ruler = plotter.add_ruler((x1, y0, z1 * z_stretch), (x1, y0, z0 * z_stretch), title=ztitle, number_labels=2,
                              label_format="%.2f", label_color="black", tick_color="black", font_size_factor=0.5)
    ruler.SetRange(z1, z0)


def legend(plotter, entries: list, entry_height: float = 0.026) -> None:
    """A legend of (label, RGB colour) entries in the top right corner, each `entry_height` of the
    window high, its box as wide as its longest label needs (VTK fits the text to the box). VTK
    writes each label in its entry's colour, so the box is dark: tab20's pale colours are
    unreadable on a light one."""
    actor = plotter.add_legend([[label, colour] for label, colour in entries], bcolor=(0.2, 0.2, 0.2),
                               border=True, face="rectangle")
    width, height = plotter.window_size
    h = min(entry_height * len(entries), 0.9)
    w = h / len(entries) * height * (0.55 * max(len(label) for label, _ in entries) + 2.0) / width
    actor.SetPosition(0.99 - w, 0.97 - h)
    actor.SetPosition2(w, h)
    actor.SetBackgroundOpacity(0.85)


def height_field_plotter(points: np.ndarray, triangles: np.ndarray, values: np.ndarray, name: str, title: str,
                         warp: float = 1.0):
    """A pyvista Plotter (off screen, not yet drawn) of a scalar height field over its 2D mesh
    (points (N, 3), triangles (M, 3), values (N,)), warped by `warp`, with its scalar bar and axes."""
    import pyvista

    cells = np.hstack([np.full((len(triangles), 1), 3), triangles]).ravel()
    grid = pyvista.PolyData(points.copy(), faces=cells)
    grid.point_data[name] = values
    grid.points[:, 2] = warp * values
    plotter = pyvista.Plotter(off_screen=True, window_size=(1200, 900))
    plotter.add_mesh(grid, scalars=name, cmap="viridis", show_edges=True, edge_color="grey", line_width=0.3,
                     scalar_bar_args={"title": f"{name} [mm]", "vertical": True, "position_x": 0.85,
                                      "position_y": 0.25})
    plotter.add_text(title, font_size=12)
    (x0, y0), (x1, y1) = points.min(axis=0)[:2], points.max(axis=0)[:2]
    mm_axes(plotter, (x0, x1, y0, y1, float(values.min()), float(values.max())), warp, z_name=name)
    plotter.view_isometric()
    plotter.camera.zoom(0.9)
    return plotter


def plot_height_field(u: dolfinx.fem.Function, path: Path, title: str, warp: float = 1.0) -> None:
    """Write a PNG of a scalar height field over its 2D mesh, warped by `warp` (collective)."""
    gathered = gather_p1_surface(u)
    if gathered is None:
        return
    with offscreen():
        points, triangles, values = gathered
        plotter = height_field_plotter(points, triangles, values, u.name, title, warp)
        plotter.screenshot(str(path))
        plotter.close()


def textile_plotter(textile, surfaces, title: str | None = None):
    """A pyvista Plotter (off screen, not yet drawn) of the textile's yarn surfaces (surfaces.YarnSurfaces,
    or None: built here at the resolution of the run's exports) in the cell's box: yarns coloured as
    in the cross-sections and named in a legend (a scalar bar of the index past MAX_LEGEND yarns),
    axes in mm, z stretched by Z_STRETCH."""
    import pyvista

    if surfaces is None:
        from textile_fenicsx.plot.surfaces import EXPORT, YarnSurfaces

        surfaces = YarnSurfaces.build(textile, resolution=EXPORT)
    mesh = surfaces.polydata()
    # to the nanometre: the axes label the scene's bounds, and a cell side at -1.4e-17 would show so
    mesh.points = np.round(mesh.points, 9) + 0.0
    n = len(textile.yarns)
    colours = yarn_colours(n)
    x0, x1, y0, y1 = (round(b, 9) + 0.0 for b in textile.cell.bounds)
    z0, z1 = float(mesh.points[:, 2].min()), float(mesh.points[:, 2].max())
    plotter = pyvista.Plotter(off_screen=True, window_size=(1600, 1000))
    if n <= MAX_LEGEND:
        mesh.cell_data["colour"] = (colours[mesh.cell_data["yarn"]] * 255).astype(np.uint8)
        plotter.add_mesh(mesh, scalars="colour", rgb=True, smooth_shading=True)
        legend(plotter, [(y.name, colours[i]) for i, y in enumerate(textile.yarns)])
    else:
        from matplotlib.colors import ListedColormap

        plotter.add_mesh(mesh, scalars="yarn", cmap=ListedColormap(colours), clim=[0, n - 1],
                         smooth_shading=True, scalar_bar_args={"title": "yarn index", "vertical": True,
                                                               "position_x": 0.88, "position_y": 0.25,
                                                               "fmt": "%.0f"})
    plotter.add_mesh(pyvista.Box((x0, x1, y0, y1, z0, z1)), style="wireframe", color="grey")
    plotter.add_text(title or textile.name, font_size=12)
    plotter.set_scale(zscale=Z_STRETCH)
    mm_axes(plotter, (x0, x1, y0, y1, z0, z1), Z_STRETCH)
    plotter.view_isometric()
    plotter.camera.zoom(0.9)  # room for the legend and the axes' labels
    return plotter


def plot_textile(textile, surfaces, path: Path, title: str | None = None) -> None:
    """Write a PNG 3D view of the textile's yarn surfaces (textile_plotter)."""
    with offscreen():
        plotter = textile_plotter(textile, surfaces, title)
        plotter.screenshot(str(path))
        plotter.close()


def projected_mesh_figure(x: np.ndarray, tags: np.ndarray, coverage: dict, title: str):
    """The matplotlib Figure of plot_projected_mesh: the triangles (x (3M, 2 or 3), three vertices
    per cell) seen from above, coloured by the set of yarns covering them (tags: each cell's set),
    named in a legend (past MAX_LEGEND sets, coloured by how many yarns cover them, with a colour
    bar), axes in mm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Patch

    polygons = x[:, :2].reshape(-1, 3, 2)
    fig, ax = plt.subplots(figsize=(10, 8))
    used = sorted(set(np.unique(tags).tolist()))
    if len(used) <= MAX_LEGEND:
        palette = np.random.default_rng(0).uniform(0.25, 0.95, size=(max(coverage) + 1, 3))
        ax.add_collection(PolyCollection(polygons, facecolors=palette[tags], edgecolors="black", linewidths=0.2))
        ax.legend(handles=[Patch(color=palette[t], label=" ".join(map(str, coverage[t])) or "none") for t in used],
                  title="yarns over the cell", loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8)
    else:
        count = np.array([len(coverage[t]) for t in tags])
        k = int(count.max())
        cmap = plt.get_cmap("viridis", k + 1)
        cells = PolyCollection(polygons, array=count, cmap=cmap, edgecolors="black", linewidths=0.2)
        cells.set_clim(-0.5, k + 0.5)
        ax.add_collection(cells)
        fig.colorbar(cells, ax=ax, ticks=range(k + 1), label="yarns over the cell")
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title(title)
    fig.tight_layout()
    return fig


def plot_projected_mesh(projected, path: Path, title: str | None = None) -> None:
    """Write a PNG of the projected mesh, cells coloured by the set of yarns covering them (collective)."""
    msh = projected.mesh
    n_owned = msh.topology.index_map(2).size_local
    tags = np.zeros(n_owned, dtype=np.int32)
    owned = projected.cell_tags.indices < n_owned
    tags[projected.cell_tags.indices[owned]] = projected.cell_tags.values[owned]
    real = np.isin(tags, list(projected.coverage))  # not the ghost strip
    x = msh.geometry.x[msh.geometry.dofmap[:n_owned][real]]
    parts = msh.comm.gather((x, tags[real]), root=0)
    if msh.comm.rank != 0:
        return
    x = np.vstack([p[0] for p in parts]).reshape(-1, 3)
    tags = np.concatenate([p[1] for p in parts])
    title = title or (f"{projected.textile.name}: {len(projected.coverage)} covering sets, "
                      f"{projected.stats.get('cells', len(x) // 3)} cells")
    import matplotlib.pyplot as plt

    fig = projected_mesh_figure(x, tags, projected.coverage, title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_cross_sections(before, after, path: Path, lines: list, n: int = 800) -> None:
    """Cross-sections of the textile before and after, along vertical cutting planes (like the
    paper's Figs 12-13). lines: [(label, (x0, y0), (x1, y1)), ...] in-plane segments."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = cross_sections_figure(before, after, lines, n)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def cross_sections_figure(before, after, lines: list, n: int = 800):
    """The matplotlib Figure of plot_cross_sections: one row per cut, before and after side by
    side, distance along the cut and z in mm, the yarns coloured as in the 3D views and named in
    a legend below. 14 inches wide, 2.6 inches per cut and 0.3 per row of the legend (8 names a
    row) high."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = yarn_colours(max(len(before.yarns), len(after.yarns)))
    rows = -(-max(len(before.yarns), len(after.yarns)) // 8)  # of the legend, 8 names a row at most
    fig, axes = plt.subplots(len(lines), 2, figsize=(14, 2.6 * len(lines) + 0.3 * rows), squeeze=False,
                             sharey=True)
    shown = {}
    for row, (label, a, b) in enumerate(lines):
        a, b = np.asarray(a, float), np.asarray(b, float)
        t = np.linspace(0, 1, n)
        xy = a + np.outer(t, b - a)
        s = t * np.linalg.norm(b - a)
        for col, (name, textile) in enumerate((("before", before), ("after", after))):
            ax = axes[row, col]
            bot, top = textile.columns(xy).envelope(len(textile.yarns))
            for i in range(len(textile.yarns)):
                if np.all(np.isnan(bot[:, i])):
                    continue
                shown[i] = ax.fill_between(s, bot[:, i], top[:, i], where=~np.isnan(bot[:, i]), color=colours[i],
                                           alpha=0.75, linewidth=0, label=textile.yarns[i].name)
            ax.set_title(f"{label}: {name}", fontsize=10)
            ax.set_xlabel("distance along the cut [mm]")
            if col == 0:
                ax.set_ylabel("z [mm]")
            ax.set_aspect("auto")
    order = sorted(shown)
    fig.legend([shown[i] for i in order], [after.yarns[i].name for i in order], loc="lower center",
               ncol=min(len(shown), 8), fontsize=9, frameon=False)
    fig.tight_layout(rect=(0, 0.3 * rows / fig.get_figheight(), 1, 1))  # room for the legend
    return fig
