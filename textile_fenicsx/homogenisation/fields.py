"""Per-cell properties: stiffness and conductivity in global axes, as numpy stacks and DG0 fields.

Cell tags (MeshTags of dimension 3): 0 = matrix, 1 + i = yarn i. The matrix is in global axes
(an orthotropic matrix has its axes 1, 2, 3 along x, y, z); a yarn cell's material axes are
constants.frames(a) of its fibre direction a (a DG0 vector field; ignored in the matrix).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import ufl
from mpi4py import MPI

import dolfinx
from textile_fenicsx.common.errors import GeometryError, TextileError
from textile_fenicsx.homogenisation.constants import (
    frames,
    orthotropic_stiffness,
    rotate_conductivity,
    rotate_stiffness,
)
from textile_fenicsx.homogenisation.materials import Material, chamis, conductivity, material, stiffness

__all__ = ["CellFields", "phase_fields", "yarn_fields"]


@dataclass
class CellFields:
    """D: DG0 6 x 6 stiffness [MPa]; K: DG0 3 x 3 conductivity [W/(m K)] or None; and, per OWNED
    cell, the same as numpy stacks (`stiffness`, `conductivity`), the cell volumes [mm^3], the
    fibre volume fraction (0 in the matrix) and whether it is a yarn cell."""
    D: dolfinx.fem.Function
    K: dolfinx.fem.Function | None
    stiffness: np.ndarray
    conductivity: np.ndarray | None
    volumes: np.ndarray
    fibre_fraction: np.ndarray
    yarn: np.ndarray


def _local_cells(mesh) -> int:
    imap = mesh.topology.index_map(mesh.topology.dim)
    return imap.size_local + imap.num_ghosts


def _tags(mesh, cell_tags) -> np.ndarray:
    """The tag of every local cell (owned and ghost); GeometryError if an owned cell has none."""
    if cell_tags.dim != mesh.topology.dim:
        raise TextileError(f"cell tags must be of dimension {mesh.topology.dim}, got {cell_tags.dim}")
    tags = np.full(_local_cells(mesh), -1, dtype=np.int64)
    tags[cell_tags.indices] = cell_tags.values
    owned = tags[: mesh.topology.index_map(mesh.topology.dim).size_local]
    bad = mesh.comm.allreduce(int((owned < 0).sum()), op=MPI.SUM)
    if bad:
        raise GeometryError(f"{bad} cell(s) have no tag or a negative one (0 = matrix, 1 + i = yarn i)")
    return tags


def _cell_values(f: dolfinx.fem.Function, n: int) -> np.ndarray:
    """(n, bs) values of a DG0 Function on local cells 0..n-1."""
    V = f.function_space
    if V.dofmap.list.shape[1] != 1:
        raise TextileError(f"{f.name}: expected a DG0 field (one value per cell)")
    bs = V.dofmap.index_map_bs
    blocks = V.dofmap.list[:n, 0]
    return f.x.array.reshape(-1, bs)[blocks]


def _volumes(mesh) -> np.ndarray:
    """Volumes of the owned cells (by quadrature of 1 on each cell)."""
    W = dolfinx.fem.functionspace(mesh, ("DG", 0))
    vec = dolfinx.fem.assemble_vector(dolfinx.fem.form(ufl.TestFunction(W) * ufl.dx))
    n = mesh.topology.index_map(mesh.topology.dim).size_local
    return vec.array.reshape(-1)[W.dofmap.list[:n, 0]]


def _directions(mesh, direction, n: int, where: np.ndarray) -> np.ndarray:
    a = _cell_values(direction, n)
    if a.shape[1] != 3:
        raise TextileError(f"the fibre direction must be a 3-vector field, got {a.shape[1]} components")
    a = np.where(where[:, None], a, [1.0, 0.0, 0.0])
    norm = np.linalg.norm(a, axis=1)
    bad = ~(norm > 1e-12)
    bad[mesh.topology.index_map(mesh.topology.dim).size_local:] = False
    count = mesh.comm.allreduce(int(bad.sum()), op=MPI.SUM)
    if count:
        raise GeometryError(f"{count} yarn cell(s) have a zero or non-finite fibre direction")
    return a / np.where(norm > 1e-12, norm, 1.0)[:, None]


def _tensor_field(mesh, values: np.ndarray, shape: tuple[int, int], name: str) -> dolfinx.fem.Function:
    V = dolfinx.fem.functionspace(mesh, ("DG", 0, shape))
    f = dolfinx.fem.Function(V, name=name)
    n = values.shape[0]
    f.x.array.reshape(-1, shape[0] * shape[1])[V.dofmap.list[:n, 0]] = values.reshape(n, -1)
    f.x.scatter_forward()
    return f


def _assemble(mesh, C: np.ndarray, K: np.ndarray | None, vf: np.ndarray, yarn: np.ndarray) -> CellFields:
    owned = mesh.topology.index_map(mesh.topology.dim).size_local
    return CellFields(
        D=_tensor_field(mesh, C, (6, 6), "stiffness"),
        K=None if K is None else _tensor_field(mesh, K, (3, 3), "conductivity"),
        stiffness=C[:owned], conductivity=None if K is None else K[:owned], volumes=_volumes(mesh),
        fibre_fraction=vf[:owned], yarn=yarn[:owned])


def yarn_fields(mesh, cell_tags, direction, yarn_vf, fibre, matrix) -> CellFields:
    """Matrix cells (tag 0) get the matrix; yarn cells the transversely isotropic yarn of Chamis'
    equations (materials.chamis) at the cell's fibre volume fraction, about its fibre direction.
    fibre, matrix: Materials, preset names or TOML paths (materials.material)."""
    fibre, matrix = material(fibre), material(matrix)
    n = _local_cells(mesh)
    yarn = _tags(mesh, cell_tags) > 0
    vf = np.where(yarn, _cell_values(yarn_vf, n)[:, 0], 0.0)
    owned = mesh.topology.index_map(mesh.topology.dim).size_local
    outside = ~((vf[:owned] >= 0) & (vf[:owned] <= 1))
    count = mesh.comm.allreduce(int(outside.sum()), op=MPI.SUM)
    if count:
        raise TextileError(f"{count} yarn cell(s) have a fibre volume fraction outside [0, 1]"
                           f"{f', e.g. {vf[:owned][outside][0]!r}' if outside.any() else ''}")
    vf = np.where((vf >= 0) & (vf <= 1), vf, 0.0)  # ghosts: set by their owners' check
    a = _directions(mesh, direction, n, yarn)
    p = chamis(fibre, matrix, vf[yarn])
    Q = frames(a[yarn])
    C = np.broadcast_to(stiffness(matrix), (n, 6, 6)).copy()
    nu23 = p["E2"] / (2 * p["G23"]) - 1
    C[yarn] = rotate_stiffness(orthotropic_stiffness(p["E1"], p["E2"], p["E2"], p["G12"], p["G12"], p["G23"],
                                                     p["nu12"], p["nu12"], nu23), Q)
    K = None
    km = conductivity(matrix)
    if km is not None and p["k1"] is not None:
        K = np.broadcast_to(km, (n, 3, 3)).copy()
        local = np.zeros((len(Q), 3, 3))
        local[:, 0, 0], local[:, 1, 1], local[:, 2, 2] = p["k1"], p["k2"], p["k2"]
        K[yarn] = rotate_conductivity(local, Q)
    return _assemble(mesh, C, K, vf, yarn)


def phase_fields(mesh, cell_tags, direction, phases: Mapping[int, Material], yarn_vf=None) -> CellFields:
    """Each tag its own material (tests and studies): phases[0] in global axes, phases[t > 0] about
    the cells' fibre direction. Conductivity only if every phase has one. yarn_vf: optional DG0 field
    for the reported fibre fraction (0 otherwise)."""
    n = _local_cells(mesh)
    tags = _tags(mesh, cell_tags)
    present = set().union(*mesh.comm.allgather(set(np.unique(tags[tags >= 0]).tolist())))
    missing = sorted(present - set(phases))
    if missing:
        raise TextileError(f"no material for cell tag(s) {missing}")
    yarn = tags > 0
    a = _directions(mesh, direction, n, yarn)
    Q = frames(a)
    C = np.zeros((n, 6, 6))  # untagged ghosts: their owners set them (scatter_forward)
    K = np.zeros((n, 3, 3)) if all(conductivity(material(m)) is not None for m in phases.values()) else None
    for tag, spec in phases.items():
        here = tags == tag
        m = material(spec)
        C[here] = rotate_stiffness(stiffness(m), Q[here]) if tag > 0 else stiffness(m)
        k = conductivity(m)
        if K is not None and k is not None:
            K[here] = rotate_conductivity(k, Q[here]) if tag > 0 else k
    vf = np.zeros(n) if yarn_vf is None else np.where(yarn, _cell_values(yarn_vf, n)[:, 0], 0.0)
    return _assemble(mesh, C, K, vf, yarn)
