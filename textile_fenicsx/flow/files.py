"""The flow fields' files: the velocity [mm/s] and pressure [Pa] of each load case j = x, y, z (a
mean pressure gradient of 1 Pa/mm along -j, the flow along +j).

- flow.xdmf (+ flow.h5), DOLFINx's XDMFFile: the mesh and, per load case, the fields velocity_j
  (3 components) and pressure_j at its vertices, each a grid of its own at t = 0 (ParaView's XDMF
  readers list them by name). XDMFFile in DOLFINx 0.9 writes only fields of the mesh's own degree,
  and the velocity is P2 (Q2 on voxels): it is interpolated into P1 (Q1), which keeps its values at
  the vertices and drops those at the edges' midpoints (and faces' and cells' centres). VTXWriter
  would keep P2, but writes ADIOS2 (.bp), not XDMF: for XDMF, P1 is the pragmatic choice. Where a
  channel is one or two elements across, most of its flow is at the dropped nodes (the cross-ply
  of tests/test_flow.py on 0.4 mm voxels: the mean of the P1 velocity is 13 % of K's).
- flow.vtu: the fields exactly, at every node of the velocity's P2 (Q2) space: VTK's quadratic
  cells (VTK_QUADRATIC_TETRA, VTK_TRIQUADRATIC_HEXAHEDRON, whose node order is fixed; VTK's
  Lagrange hexahedra changed theirs in VTK 9.1, and files of an older version are read renumbered),
  which VTK interpolates as the elements do (ParaView draws them finer with its "Nonlinear
  Subdivision Level"); point data velocity_j and pressure_j (P1 in P2: exact), gathered on rank 0
  and written by meshio as volume.vtu is (volume/files.py's save_vtu).
- flow.png: the velocity magnitude on cuts, a row per load case (plot/flow_figures.py, drawn from
  flow.vtu on rank 0).

The pressure is the periodic part p of the solution, defined up to a constant: the solver holds it
at 0 at one node, which moves with the number of ranks, so only its differences mean anything. The
whole pressure of load case j is p - (x_j - x0_j) 1 Pa/mm. The velocity is linear in the gradient
and in 1 / mu. The files are the same on any number of ranks (but for that constant).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import dolfinx
from textile_fenicsx.common.files import naming

__all__ = ["CASES", "FILES", "gather_nodes", "split", "vtk_cells", "write_flow", "write_vtu", "write_xdmf"]

FILES = ("flow.xdmf", "flow.h5", "flow.vtu", "flow.png")
CASES = ("x", "y", "z")  # the load cases' gradient directions, in the order of the solves
# VTK's quadratic cells (VTK_QUADRATIC_TETRA, VTK_TRIQUADRATIC_HEXAHEDRON; meshio's tetra10 and
# hexahedron27) by their number of vertices: meshio's name, and their nodes past the vertices, each
# the centre of the vertices listed (VTK's numbers of the vertices)
_QUADRATIC = {
    4: ("tetra10", ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))),
    8: ("hexahedron27", ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6),
                         (3, 7), (0, 4, 7, 3), (1, 2, 6, 5), (0, 1, 5, 4), (3, 2, 6, 7), (0, 1, 2, 3), (4, 5, 6, 7),
                         (0, 1, 2, 3, 4, 5, 6, 7))),
}

Fields = list[tuple[dolfinx.fem.Function, dolfinx.fem.Function]]


def split(flows: list[dolfinx.fem.Function]) -> Fields:
    """The velocity (P2) and pressure (P1) of each load case (flows: mixed Taylor-Hood Functions, in
    CASES' order), named velocity_j and pressure_j; each kind in one space."""
    W = flows[0].function_space
    (V, velocity), (Q, pressure) = W.sub(0).collapse(), W.sub(1).collapse()
    out = []
    for case, w in zip(CASES, flows):
        u, p = dolfinx.fem.Function(V, name=f"velocity_{case}"), dolfinx.fem.Function(Q, name=f"pressure_{case}")
        u.x.array[:] = w.x.array[velocity]
        p.x.array[:] = w.x.array[pressure]
        out.append((u, p))
    return out


def write_xdmf(fields: Fields, path: Path) -> None:
    """flow.xdmf (+ .h5 beside it): the mesh and every field at its vertices (the velocity
    interpolated into P1; module docstring; collective)."""
    msh = fields[0][0].function_space.mesh
    V1 = dolfinx.fem.functionspace(msh, ("Lagrange", 1, (3,)))
    with naming(path), dolfinx.io.XDMFFile(msh.comm, str(path), "w") as f:
        f.write_mesh(msh)
        for u, p in fields:
            u1 = dolfinx.fem.Function(V1, name=u.name)
            u1.interpolate(u)
            f.write_function(u1, 0.0)
            f.write_function(p, 0.0)


def vtk_cells(V: dolfinx.fem.FunctionSpace) -> tuple[np.ndarray, str]:
    """The owned cells of a degree-2 Lagrange space V on a degree-1 mesh as VTK's quadratic cells:
    each cell's nodes (local indices of V's blocks) in VTK's order, and meshio's name of the cell.
    The order is found by location (VTK's node k at the centre of the vertices _QUADRATIC lists),
    on the first cell, and checked on every cell (RuntimeError where a node is elsewhere)."""
    msh = V.mesh
    owned = msh.topology.index_map(3).size_local
    vertices = msh.geometry.dofmap[:owned]
    vertices = vertices[:, np.argsort(dolfinx.cpp.io.perm_vtk(msh.topology.cell_type, vertices.shape[1]))]
    name, centres = _QUADRATIC[vertices.shape[1]]
    dofs, x = V.dofmap.list[:owned], V.tabulate_dof_coordinates()
    if dofs.shape[1] != vertices.shape[1] + len(centres):
        raise RuntimeError(f"flow.vtu: {dofs.shape[1]} velocity nodes a cell, not the quadratic cell's "
                           f"{vertices.shape[1] + len(centres)}")
    order = None
    for start in range(0, owned, 65536):  # (chunk, nodes, 3) at a time
        corners = msh.geometry.x[vertices[start:start + 65536]]
        expected = np.concatenate([corners] + [corners[:, list(c)].mean(axis=1, keepdims=True) for c in centres],
                                  axis=1)
        if order is None:
            order = np.argmin(np.linalg.norm(expected[0][:, None] - x[dofs[0]][None], axis=2), axis=1)
        size = np.ptp(corners, axis=1).max()
        if np.abs(x[dofs[start:start + 65536][:, order]] - expected).max() > 1e-9 * size:
            raise RuntimeError("flow.vtu: the velocity's nodes are not where VTK's quadratic cell has them")
    return (dofs[:, order] if order is not None else dofs), name


def gather_nodes(fields: Fields) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], str] | None:
    """Every node of the velocity's space with the fields there, on rank 0 (None elsewhere;
    collective): points (N, 3) sorted by z, then y, then x, cells (M, 10 or 27: vtk_cells) in the
    order of the mesh's input cells (both the same on any number of ranks), {name: values (N, 3)
    or (N,)} and meshio's name of the cells."""
    V = fields[0][0].function_space
    msh = V.mesh
    owned = msh.topology.index_map(3).size_local
    cells, kind = vtk_cells(V)
    local, inverse = np.unique(cells, return_inverse=True)
    inverse = inverse.reshape(cells.shape)
    # the pressure in the velocity's element (exact: P1 in P2); a cell's nodes are in the element's
    # order in every space of that element, whatever their numbers
    S = dolfinx.fem.functionspace(msh, ("Lagrange", 2))
    s_cells, _ = vtk_cells(S)
    p2 = dolfinx.fem.Function(S)
    values: dict[str, np.ndarray] = {}
    for u, p in fields:
        values[u.name] = u.x.array.reshape(-1, 3)[local]
        p2.interpolate(p)
        at = np.empty(len(local))
        at[inverse] = p2.x.array[s_cells]
        values[p.name] = at
    part = (V.dofmap.index_map.local_to_global(local.astype(np.int32)), V.tabulate_dof_coordinates()[local],
            inverse, np.asarray(msh.topology.original_cell_index)[:owned], values)
    parts = msh.comm.gather(part, root=0)
    if parts is None:
        return None
    numbers, first = np.unique(np.concatenate([q[0] for q in parts]), return_index=True)  # a shared node once
    points = np.round(np.vstack([q[1] for q in parts])[first], 12) + 0.0  # no -1e-17 mm in ParaView's ranges
    # the nodes by location, as the cells by their input order: the same file on any number of ranks
    by = np.lexsort((points[:, 0], points[:, 1], points[:, 2]))
    place = np.empty(len(by), np.int64)
    place[by] = np.arange(len(by))
    every = np.vstack([place[np.searchsorted(numbers, q[0][q[2]])] for q in parts])
    order = np.argsort(np.concatenate([q[3] for q in parts]))
    data = {name: np.concatenate([q[4][name] for q in parts])[first][by] for name in parts[0][4]}
    return points[by], every[order], data, kind


def write_vtu(gathered: tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], str], path: Path) -> None:
    """flow.vtu from what gather_nodes returned on rank 0: the fields as point data."""
    from textile_fenicsx.volume.files import save_vtu

    points, cells, data, kind = gathered
    save_vtu(points, cells, path, point_data=data, kind=kind)


def write_flow(flows: list[dolfinx.fem.Function], folder: Path, mu: float = 1.0, K: np.ndarray | None = None
               ) -> list[Path]:
    """Every file of FILES into `folder` (collective; rank 0 writes flow.vtu and flow.png). mu: the
    viscosity the flows were solved with [Pa s]; K: the cell's permeability [mm^2] (for the figure's
    titles), or None."""
    from textile_fenicsx.common.parallel import wait_asleep
    from textile_fenicsx.plot.flow_figures import flow_cuts

    folder = Path(folder)
    fields = split(flows)
    write_xdmf(fields, folder / "flow.xdmf")
    gathered = gather_nodes(fields)
    if gathered is not None:
        write_vtu(gathered, folder / "flow.vtu")
        flow_cuts(folder / "flow.vtu", folder / "flow.png", mu, K)
    wait_asleep(flows[0].function_space.mesh.comm)  # the other ranks leave rank 0 the cores while it draws
    return [folder / name for name in FILES]
