"""Pictures of volume meshes and their cell problems (matplotlib; axes in mm, legends, colour bars).

- `phase_cuts`: cuts of volume meshes (their volume.vtu) by a plane y = const, elements coloured
  by phase (the matrix grey, each yarn its colour of every other figure: plotting.yarn_colours).
- `strain_energy_cut`: one elastic cell problem solved again, its strain energy density per
  element on the same cut (collective; rank 0 draws).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from textile_fenicsx.common.files import naming


def _cut(grid: Any, y: float) -> tuple[list[np.ndarray], dict[str, np.ndarray]]:
    """The polygons (x, z) of a pyvista grid cut by the plane y = const, and their cell data."""
    cut = grid.slice(normal="y", origin=(0.0, y, 0.0))
    faces, polygons, k = np.asarray(cut.faces), [], 0
    while k < len(faces):
        n = int(faces[k])
        polygons.append(np.asarray(cut.points)[faces[k + 1:k + 1 + n]][:, [0, 2]])
        k += n + 1
    return polygons, {name: np.asarray(cut.cell_data[name]) for name in cut.cell_data.keys()}


# Through-thickness exaggeration of the cuts: a fabric is 10-20 times thinner than its cell is long.
Z_STRETCH = 3.0


def _axes(ax: Any, polygons: list[np.ndarray], title: str) -> None:
    pts = np.concatenate(polygons)
    ax.set_xlim(pts[:, 0].min(), pts[:, 0].max())
    ax.set_ylim(pts[:, 1].min(), pts[:, 1].max())
    ax.set_aspect(Z_STRETCH)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel(f"z [mm], drawn x{Z_STRETCH:g}")
    ax.set_title(title, fontsize=9)


def phase_cuts(meshes: dict[str, Path], y: float, path: Path) -> Path:
    """One panel per volume mesh (name -> its volume.vtu): the cut y = const [mm], elements coloured
    by phase with their edges, a legend of the phases met."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pyvista
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Patch

    from textile_fenicsx.plot.plotting import yarn_colours

    fig, axes = plt.subplots(len(meshes), 1, figsize=(10, 1.0 + 2.2 * len(meshes)), squeeze=False)
    seen: dict[int, Any] = {}
    for ax, (name, vtu) in zip(axes[:, 0], meshes.items()):
        polygons, data = _cut(pyvista.read(vtu), y)
        phase = data["phase"].astype(int)
        colours = np.vstack([[0.82, 0.82, 0.82], yarn_colours(int(phase.max()))])
        ax.add_collection(PolyCollection(polygons, facecolors=colours[phase], edgecolors="black", linewidths=0.1))
        _axes(ax, polygons, f"{name}: cut at y = {y:g} mm")
        for p in np.unique(phase):
            seen[int(p)] = colours[p]
    handles = [Patch(color=c, label="matrix" if p == 0 else f"yarn {p - 1}") for p, c in sorted(seen.items())]
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 9), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    with naming(path):
        fig.savefig(path, dpi=150)
    plt.close(fig)
    return Path(path)


def strain_energy_cut(fields: Any, fibre: str, matrix: str, case: int, strain: float, y: float, path: Path,
                      degree: int = 2) -> Path:
    """The strain energy density [kJ/m^3] of load case `case` (Voigt index: 0 = xx ... 5 = xy) at a
    mean strain `strain` [-], per element (at its centre), on the cut y = const [mm] of the meshed
    cell `fields` (volume_files.VolumeFields); collective, rank 0 draws."""
    import basix.ufl

    import dolfinx
    from textile_fenicsx.homogenisation.cellproblem import default_solver
    from textile_fenicsx.homogenisation.elasticity import ElasticCellProblem
    from textile_fenicsx.homogenisation.elasticity_forms import elastic_energy_density, voigt_strain
    from textile_fenicsx.homogenisation.elasticity_forms import strain as eps
    from textile_fenicsx.homogenisation.fields import yarn_fields
    from textile_fenicsx.homogenisation.materials import material
    from textile_fenicsx.homogenisation.periodic import bounding_box

    msh = fields.mesh
    cell = yarn_fields(msh, fields.phase, fields.direction, fields.yarn_vf, material(fibre), material(matrix))
    problem = ElasticCellProblem(cell.D, bounding_box(msh), default_solver(degree), degree)
    try:
        load = np.zeros(6)
        load[case] = strain
        v = problem.solve([load], keep=True)["fluctuations"][0]
    finally:
        problem.destroy()
    E = dolfinx.fem.Constant(msh, load)
    total = E + voigt_strain(eps(v))
    W = dolfinx.fem.functionspace(msh, basix.ufl.element("DG", msh.basix_cell(), 0))
    psi = dolfinx.fem.Function(W, name="strain_energy_density")
    psi.interpolate(dolfinx.fem.Expression(elastic_energy_density(cell.D, total) * 1e3,  # MPa -> kJ/m^3
                                           W.element.interpolation_points()))
    grid = _gathered_grid(msh, psi)
    if msh.comm.rank == 0:
        _energy_figure(grid, y, path, case, strain)
    return Path(path)


def _gathered_grid(msh: Any, psi: Any) -> Any:
    """The mesh's owned cells with psi as cell data, gathered on rank 0 as one pyvista grid."""
    import pyvista

    import dolfinx.plot

    owned = msh.topology.index_map(3).size_local
    topology, types, x = dolfinx.plot.vtk_mesh(msh, 3, np.arange(owned, dtype=np.int32))
    parts = msh.comm.gather((topology, types, x, psi.x.array[:owned].copy()), root=0)
    if msh.comm.rank != 0:
        return None
    grids = []
    for top, typ, pts, values in parts:
        g = pyvista.UnstructuredGrid(top, typ, pts)
        g.cell_data["psi"] = values
        grids.append(g)
    return grids[0].merge(grids[1:]) if len(grids) > 1 else grids[0]


def _energy_figure(grid: Any, y: float, path: Path, case: int, strain: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    polygons, data = _cut(grid, y)
    fig, ax = plt.subplots(figsize=(10, 3.6))
    coll = PolyCollection(polygons, array=data["psi"], cmap="viridis", edgecolors="none")
    ax.add_collection(coll)
    name = ("xx", "yy", "zz", "yz", "xz", "xy")[case]
    _axes(ax, polygons, f"strain energy density, mean strain {name} = {100 * strain:g} %, cut at y = {y:g} mm")
    fig.colorbar(coll, ax=ax, label="strain energy density [kJ/m^3]", fraction=0.04)
    fig.tight_layout()
    with naming(path):
        fig.savefig(path, dpi=150)
    plt.close(fig)


__all__ = ["phase_cuts", "strain_energy_cut"]
