"""A volume mesh in DOLFINx, and its files (README: "The volume mesh folder").

- `to_dolfinx`: the mesh (built on rank 0) distributed by DOLFINx, with its phases as cell tags and
  the fibre direction and fibre fraction as DG0 fields.
- `write_volume`: volume.xdmf + volume.h5 (DOLFINx's own XDMF: the mesh, the cell tags "phase" and
  the DG0 fields "direction" and "yarn_vf"; `read_volume` reads it back on any number of ranks),
  volume.msh (gmsh 4.1 by gmsh: a volume entity and a physical group per phase, "matrix" = 1 and
  the yarns 2, 3, ... by name), volume.vtu (ParaView: phase, direction, yarn_vf as cell data;
  written by `save_vtu`, which writes the flow stage's flow.vtu too), volume.inp (Abaqus: an
  element set per yarn and for the matrix, *Orientation by a distribution per element: local axis
  1 the fibre direction) and mesh_report.json.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import basix.ufl
import numpy as np
from mpi4py import MPI

import dolfinx
from textile_fenicsx.common.errors import FormatError
from textile_fenicsx.common.files import naming
from textile_fenicsx.volume.box import VolumeMesh

FILES = ("volume.xdmf", "volume.h5", "volume.msh", "volume.vtu", "volume.inp", "mesh_report.json")
_CELL = {8: ("hexahedron", dolfinx.mesh.CellType.hexahedron), 4: ("tetra", dolfinx.mesh.CellType.tetrahedron)}


@dataclass(eq=False)
class VolumeFields:
    """A volume mesh in DOLFINx: the mesh, its phases as cell tags (0 matrix, 1 + i yarn i), the
    DG0 fibre direction (unit vectors) and DG0 intra-yarn fibre fraction."""

    mesh: dolfinx.mesh.Mesh
    phase: dolfinx.mesh.MeshTags
    direction: dolfinx.fem.Function
    yarn_vf: dolfinx.fem.Function

    def __repr__(self) -> str:
        cells = self.mesh.topology.index_map(3).size_global
        return f"VolumeFields({self.mesh.topology.cell_name()}, {cells} cells)"


def _fields(msh: dolfinx.mesh.Mesh, phase: np.ndarray, direction: np.ndarray, vf: np.ndarray,
            original: np.ndarray) -> VolumeFields:
    """Cell tags and DG0 fields of a mesh whose local cells (owned, then ghosts) are the input cells
    `original` of the global arrays phase (E,), direction (E, 3), vf (E,)."""
    owned = msh.topology.index_map(3).size_local
    cells = np.arange(owned, dtype=np.int32)
    tags = dolfinx.mesh.meshtags(msh, 3, cells, phase[original[:owned]].astype(np.int32))
    tags.name = "phase"
    V = dolfinx.fem.functionspace(msh, basix.ufl.element("DG", msh.basix_cell(), 0, shape=(3,)))
    W = dolfinx.fem.functionspace(msh, ("DG", 0))
    d = dolfinx.fem.Function(V, name="direction")
    f = dolfinx.fem.Function(W, name="yarn_vf")
    local = np.arange(len(original), dtype=np.int32)
    dofs_v = V.dofmap.list[local, 0]
    d.x.array.reshape(-1, 3)[dofs_v] = direction[original]
    f.x.array[W.dofmap.list[local, 0]] = vf[original]
    return VolumeFields(msh, tags, d, f)


def to_dolfinx(vm: VolumeMesh | None, comm: MPI.Comm = MPI.COMM_WORLD) -> VolumeFields:
    """The volume mesh (given on rank 0; None elsewhere) as a distributed DOLFINx mesh with its fields."""
    nodes = comm.bcast(vm.cells.shape[1] if vm is not None else None, root=0)
    name, cell_type = _CELL[nodes]
    element = basix.ufl.element("Lagrange", name if name != "tetra" else "tetrahedron", 1, shape=(3,))
    if comm.rank == 0:
        assert vm is not None
        cells = vm.cells[:, dolfinx.io.gmshio.cell_perm_array(cell_type, nodes)].astype(np.int64)
        x = vm.points
        arrays = (vm.phase.astype(np.int32), vm.direction, vm.yarn_vf)
    else:
        cells, x, arrays = np.zeros((0, nodes), np.int64), np.zeros((0, 3)), None
    msh = dolfinx.mesh.create_mesh(comm, cells, x, element)
    phase, direction, vf = comm.bcast(arrays, root=0)
    return _fields(msh, phase, direction, vf, np.asarray(msh.topology.original_cell_index))


def write_xdmf(fields: VolumeFields, path: Path) -> None:
    """volume.xdmf (+ .h5 beside it): mesh, phase tags and the two DG0 fields (collective)."""
    with naming(path), dolfinx.io.XDMFFile(fields.mesh.comm, str(path), "w") as f:
        f.write_mesh(fields.mesh)
        f.write_meshtags(fields.phase, fields.mesh.geometry)
        f.write_function(fields.direction)
        f.write_function(fields.yarn_vf)


def read_volume(path: str | Path, comm: MPI.Comm = MPI.COMM_WORLD) -> VolumeFields:
    """A volume mesh written by `write_volume` (volume.xdmf with its .h5), on any number of ranks.
    A file without the phase tags or the fields is refused (FormatError naming what is missing)."""
    path = Path(path)
    names = None
    if comm.rank == 0:
        names = _xdmf_grids(path)
    names = comm.bcast(names, root=0)
    if isinstance(names, Exception):
        raise names
    missing = [n for n in ("mesh", "phase", "direction", "yarn_vf") if n not in names]
    if missing:
        raise FormatError(f"{path}: no {', '.join(missing)} in this XDMF file: a volume mesh needs its phase tags "
                          "and fields (write it with `textile-fenicsx volume-mesh`)")
    with dolfinx.io.XDMFFile(comm, str(path), "r") as f:
        msh = f.read_mesh(name="mesh")
        msh.topology.create_connectivity(3, 0)
        tags = f.read_meshtags(msh, "phase")
    arrays = None
    if comm.rank == 0:
        import h5py

        with h5py.File(path.with_suffix(".h5"), "r") as h5:
            arrays = (np.asarray(h5[names["direction"]]).reshape(-1, 3), np.asarray(h5[names["yarn_vf"]]).ravel())
    direction, vf = comm.bcast(arrays, root=0)
    original = np.asarray(msh.topology.original_cell_index)
    owned = msh.topology.index_map(3).size_local
    # the tags as DOLFINx read them, spread to the ghost cells too
    phase_local = np.zeros(len(original), np.int32)
    phase_local[tags.indices] = tags.values
    phase_all = np.zeros(len(direction), np.int32)
    phase_all[original[:owned]] = phase_local[:owned]
    phase_all = comm.allreduce(phase_all, op=MPI.SUM)
    return _fields(msh, phase_all, direction, vf, original)


def _xdmf_grids(path: Path) -> dict | Exception:
    """The HDF5 dataset of each grid's data in an XDMF file: {"mesh": ..., "phase": ..., field: dataset}."""
    try:
        with naming(path):
            root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as e:
        return FormatError(f"{path}: not a readable XDMF file ({e})")
    out = {}
    for grid in root.iter("Grid"):
        name = grid.get("Name")
        attr = grid.find("Attribute/DataItem")
        if grid.get("GridType") == "Uniform" and name is not None:
            out[name] = attr.text.split(":", 1)[1] if attr is not None and attr.text else None
    return out


def write_volume(vm: VolumeMesh | None, fields: VolumeFields, folder: Path,
                 materials: dict[str, list[str]] | None = None) -> list[Path]:
    """Every file of the volume mesh into `folder` (collective; the mesh arrays on rank 0)."""
    comm = fields.mesh.comm
    write_xdmf(fields, folder / "volume.xdmf")
    written = [folder / "volume.xdmf", folder / "volume.h5"]
    if comm.rank == 0:
        assert vm is not None
        write_msh(vm, folder / "volume.msh")
        write_vtu(vm, folder / "volume.vtu")
        write_inp(vm, folder / "volume.inp", materials)
        with naming(folder / "mesh_report.json"), open(folder / "mesh_report.json", "w") as f:
            json.dump(report_document(vm), f, indent=1)
    return written + [folder / n for n in FILES[2:]]


def report_document(vm: VolumeMesh) -> dict:
    """mesh_report.json: the mesher's report, the box, the phases' volumes and the cell's fibre fraction."""
    volumes = np.abs(vm.element_volumes())
    phases = vm.phase_volumes()
    return {**vm.report, "box": {"lo": list(vm.box.lo), "hi": list(vm.box.hi)},
            "volume": {"cell": vm.box.volume, "matrix": float(phases[0]), "yarns": float(phases[1:].sum())},
            "vf": float(np.dot(vm.yarn_vf, volumes) / vm.box.volume),
            "phases": {"0": "matrix", **{str(i + 1): n for i, n in enumerate(vm.yarn_names)}},
            "units": "mm, mm^3"}


def save_vtu(points: np.ndarray, cells: np.ndarray, path: Path, point_data: dict[str, np.ndarray] | None = None,
             cell_data: dict[str, np.ndarray] | None = None, kind: str | None = None) -> None:
    """A .vtu for ParaView, written by meshio: one kind of cell (meshio's name, e.g. "hexahedron27";
    by default a tetra for 4 nodes, a hexahedron for 8), its nodes in VTK's order, data by name at
    the points (N, ...) and at the cells (M, ...)."""
    import meshio

    mesh = meshio.Mesh(points, [(kind or _CELL[cells.shape[1]][0], cells)], point_data=point_data or {},
                       cell_data={name: [values] for name, values in (cell_data or {}).items()})
    with naming(path):
        mesh.write(path, binary=True)


# gmsh's element types of the volume meshes' cells (its node order is VTK's and meshio's for both)
_GMSH_TYPE = {8: 5, 4: 4}


def write_msh(vm: VolumeMesh, path: Path) -> None:
    """gmsh 4.1, written by gmsh itself: one discrete volume entity per phase (tag 1 the matrix, 2 + i
    yarn i) holding that phase's elements, and a physical group of the same tag and the phase's name
    on each, so that gmsh opens the file with the phases as groups (and meshio reads them back as
    "gmsh:physical"). Phases with no element get no entity."""
    import gmsh

    names = ["matrix", *vm.yarn_names]
    initialised = gmsh.isInitialized()
    if not initialised:
        gmsh.initialize(interruptible=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("textile_fenicsx volume")
    try:
        phases = [p for p in range(len(names)) if np.any(vm.phase == p)]
        for p in phases:
            gmsh.model.addDiscreteEntity(3, p + 1)
        nodes = np.arange(1, len(vm.points) + 1)
        gmsh.model.mesh.addNodes(3, phases[0] + 1, nodes, vm.points.ravel())
        for p in phases:
            members = np.flatnonzero(vm.phase == p)
            gmsh.model.mesh.addElementsByType(p + 1, _GMSH_TYPE[vm.cells.shape[1]], members + 1,
                                              (vm.cells[members] + 1).ravel())
            gmsh.model.addPhysicalGroup(3, [p + 1], p + 1, name=names[p])
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.option.setNumber("Mesh.Binary", 0)
        with naming(path):
            gmsh.write(str(path))
    finally:
        gmsh.model.remove()
        if not initialised:
            gmsh.finalize()


def write_vtu(vm: VolumeMesh, path: Path) -> None:
    """VTU for ParaView: cell data phase, direction, yarn_vf."""
    save_vtu(vm.points, vm.cells, path, cell_data={"phase": vm.phase.astype(np.int32), "direction": vm.direction,
                                                    "yarn_vf": vm.yarn_vf})


def _second_axis(a: np.ndarray) -> np.ndarray:
    """A unit vector normal to each fibre direction (in the plane of a and z where a is not vertical)."""
    ref = np.where(np.abs(a[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    b = np.cross(ref, a)
    return b / np.linalg.norm(b, axis=1, keepdims=True)


def _rows(f: Any, fmt: str, table: np.ndarray) -> None:
    """The table's rows, each formatted by fmt, on lines of the open text file f."""
    np.savetxt(f, table, fmt=fmt)


def write_inp(vm: VolumeMesh, path: Path, materials: dict[str, list[str]] | None = None) -> None:
    """Abaqus input: nodes, elements, an element set per phase, and per yarn element its material
    axes by a distribution (*Orientation): axis 1 the fibre direction, axis 2 normal to it.
    `materials`: {phase name: lines of a *Material block} to include; without it each section names
    a material (MATRIX, YARN0, ...) for the user to define."""
    etype = "C3D8" if vm.cells.shape[1] == 8 else "C3D4"
    names = ["MATRIX"] + [f"YARN{i}" for i in range(len(vm.yarn_names))]
    yarn = np.flatnonzero(vm.phase > 0)
    a = vm.direction[yarn]
    b = _second_axis(a) if len(yarn) else a
    with naming(path), open(path, "w") as f:
        f.write("*Heading\n** textile_fenicsx volume mesh (mm); phases: MATRIX, "
                + ", ".join(f"YARN{i} = {n}" for i, n in enumerate(vm.yarn_names)) + "\n")
        f.write("*Node\n")
        _rows(f, "%d, %.12g, %.12g, %.12g", np.column_stack((np.arange(1, len(vm.points) + 1), vm.points)))
        f.write(f"*Element, type={etype}\n")
        _rows(f, ", ".join(["%d"] * (vm.cells.shape[1] + 1)), np.column_stack((np.arange(1, len(vm.cells) + 1),
                                                                                vm.cells + 1)))
        for p, name in enumerate(names):
            members = np.flatnonzero(vm.phase == p) + 1
            f.write(f"*Elset, elset={name}\n")
            for k in range(0, len(members), 16):
                f.write(", ".join(map(str, members[k:k + 16])) + "\n")
        f.write("*Distribution Table, name=FIBRE_AXES_TABLE\ncoord3d, coord3d\n")
        f.write("*Distribution, name=FIBRE_AXES, location=ELEMENT, table=FIBRE_AXES_TABLE\n, 1., 0., 0., 0., 1., 0.\n")
        _rows(f, "%d, %.9g, %.9g, %.9g, %.9g, %.9g, %.9g", np.column_stack((yarn + 1, a, b)))
        f.write("*Orientation, name=FIBRE_AXES, definition=COORDINATES, system=RECTANGULAR\nFIBRE_AXES\n1, 0.\n")
        for p, name in enumerate(names):
            orient = ", orientation=FIBRE_AXES" if p > 0 else ""
            f.write(f"*Solid Section, elset={name}, material={name}{orient}\n,\n")
        for lines in (materials or {}).values():
            f.write("\n".join(lines) + "\n")
