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

import numpy as np


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


def plot_height_field(u: dolfinx.fem.Function, path: Path, title: str, warp: float = 1.0) -> None:
    """Write a PNG of a scalar height field over its 2D mesh, warped by `warp` (collective)."""
    gathered = gather_p1_surface(u)
    if gathered is None:
        return
    import pyvista

    points, triangles, values = gathered
    cells = np.hstack([np.full((len(triangles), 1), 3), triangles]).ravel()
    grid = pyvista.PolyData(points.copy(), faces=cells)
    grid.point_data[u.name] = values
    grid.points[:, 2] = warp * values
    with offscreen():
        plotter = pyvista.Plotter(off_screen=True, window_size=(1200, 900))
        plotter.add_mesh(grid, scalars=u.name, cmap="viridis", show_edges=True, edge_color="grey",
                         line_width=0.3, scalar_bar_args={"title": u.name})
        plotter.add_text(title, font_size=12)
        plotter.view_isometric()
        plotter.screenshot(str(path))
        plotter.close()


def plot_textile(textile, surfaces, path: Path, title: str | None = None) -> None:
    """Write a PNG 3D view of the textile's yarn surfaces (surfaces.YarnSurfaces, or None: built
    here at the resolution of the run's exports), coloured by yarn."""
    import pyvista

    if surfaces is None:
        from textile_fenicsx.surfaces import EXPORT, YarnSurfaces

        surfaces = YarnSurfaces.build(textile, resolution=EXPORT)
    mesh = surfaces.polydata()
    points = surfaces.points
    x0, x1, y0, y1 = textile.cell.bounds
    with offscreen():
        plotter = pyvista.Plotter(off_screen=True, window_size=(1400, 1000))
        plotter.add_mesh(mesh, scalars="yarn", cmap="tab20", show_scalar_bar=False, smooth_shading=True)
        plotter.add_mesh(pyvista.Box((x0, x1, y0, y1, points[:, 2].min(), points[:, 2].max())),
                         style="wireframe", color="grey")
        plotter.add_text(title or textile.name, font_size=12)
        plotter.set_scale(zscale=2.0)
        plotter.view_isometric()
        plotter.screenshot(str(path))
        plotter.close()


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
    import pyvista

    x = np.vstack([p[0] for p in parts]).reshape(-1, 3)
    tags = np.concatenate([p[1] for p in parts])
    tri = np.arange(len(x)).reshape(-1, 3)
    grid = pyvista.PolyData(x, np.hstack([np.full((len(tri), 1), 3), tri]).ravel())
    labels = {t: " ".join(map(str, s)) or "-" for t, s in projected.coverage.items()}
    n_yarns = np.array([len(projected.coverage[t]) for t in tags])
    grid.cell_data["covering yarns"] = n_yarns
    rng = np.random.default_rng(0)
    palette = rng.uniform(0.25, 0.95, size=(max(projected.coverage) + 1, 3))
    grid.cell_data["colour"] = (palette[tags] * 255).astype(np.uint8)
    with offscreen():
        plotter = pyvista.Plotter(off_screen=True, window_size=(1200, 1200))
        plotter.add_mesh(grid, scalars="colour", rgb=True, show_edges=True, edge_color="black", line_width=0.5)
        plotter.add_text(title or f"{projected.textile.name}: {len(labels)} covering sets, "
                         f"{projected.stats.get('cells', len(tri))} cells", font_size=12)
        plotter.view_xy()
        plotter.screenshot(str(path))
        plotter.close()


def plot_cross_sections(before, after, path: Path, lines: list, n: int = 800) -> None:
    """Cross-sections of the textile before and after, along vertical cutting planes (like the
    paper's Figs 12-13). lines: [(label, (x0, y0), (x1, y1)), ...] in-plane segments."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = plt.get_cmap("tab20")
    fig, axes = plt.subplots(len(lines), 2, figsize=(14, 2.6 * len(lines)), squeeze=False, sharey=True)
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
                ax.fill_between(s, bot[:, i], top[:, i], where=~np.isnan(bot[:, i]), color=colours(i % 20),
                                alpha=0.75, linewidth=0, label=textile.yarns[i].name)
            ax.set_title(f"{label}: {name}", fontsize=10)
            ax.set_xlabel("distance along the cut [mm]")
            if col == 0:
                ax.set_ylabel("z [mm]")
            ax.set_aspect("auto")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
