"""The volume-mesh stage: a textile model -> a periodic volume mesh with its fields (DESIGN.md 12).

`volume_mesh(textile, options, comm)` picks the cell (`meshes.volume.cell_box`), each yarn's fibre
volume fraction (the model's fibre data, or `options.yarn_vf`, or the stated default), checks the
memory, and runs the mesher of `options.kind` on rank 0: `volume.voxel` or `volume.tet`.
`mesh_cell(...)` does that and distributes the mesh to DOLFINx: a `CellMesh`, which writes the files.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from mpi4py import MPI

from textile_fenicsx.common import limits
from textile_fenicsx.common.errors import MeshError, TextileError
from textile_fenicsx.common.parallel import wait_asleep
from textile_fenicsx.model.fibres import HEXAGONAL, check_yarn_vf
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.box import DEFAULT_SIZE, KINDS, VolumeMesh, cell_box
from textile_fenicsx.volume.voxel import check_sizes

if TYPE_CHECKING:
    from textile_fenicsx.volume.files import VolumeFields

log = logging.getLogger(__name__)

MAX_LAYERS = 1000  # voxels through the thickness a mesh may be asked for (VolumeOptions.layers)


@dataclass(frozen=True)
class VolumeOptions:
    """How to mesh the cell.

    kind: "voxel" (hexahedra, phase at their centres) or "tet" (conforming tetrahedra).
    size: element size [mm]: one H, or for voxels (HX, HY, HZ), one per axis (None: voxel, the
    default grid of voxel.default_grid, from the yarns' heights and widths; tet, DEFAULT_SIZE).
    yarn_vf: every yarn's intra-yarn fibre volume fraction [-], instead of the model's fibre data.
    z_range: the cell through the thickness (zmin, zmax) [mm], e.g. a mould's cavity; None: the
    yarns' own extent (tet: padded by half the gap). gap: tet only, the least gap between yarns the
    mesh is made for [mm] (volume.tet: default 5 % of the thinnest yarn's height). memory_limit:
    largest memory [GB] the mesh may take (default: what the system has available). layers: voxel
    only, the voxels through the thickness (default: the thickness over the size along z, rounded).
    scale: every element size, given or default, times this [-] (a coarser or finer mesh of the same
    rule, for grid convergence: volume/refinement.py; voxel layers given are divided by it).
    """

    kind: str = "voxel"
    size: float | tuple[float, ...] | None = None
    yarn_vf: float | None = None
    z_range: tuple[float, float] | None = None
    gap: float | None = None
    memory_limit: float | None = None
    layers: int | None = None
    scale: float = 1.0

    @property
    def element_size(self) -> float:
        """A tet mesh's size: size, or DEFAULT_SIZE [mm]."""
        assert self.kind == "tet" and not isinstance(self.size, tuple)
        return DEFAULT_SIZE["tet"] if self.size is None else self.size

    @property
    def voxel_sizes(self) -> tuple[float, float, float] | None:
        """A voxel mesh's (hx, hy, hz) [mm], or None for the default rule."""
        assert self.kind == "voxel"
        return None if self.size is None else check_sizes(self.size)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise TextileError(f"volume mesh kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        if self.size is not None and np.ndim(self.size) > 0:
            size = tuple(np.ravel(np.asarray(self.size, dtype=object)).tolist())
            if self.kind == "tet" and len(size) != 1:
                raise TextileError(f"a tet mesh takes one size H [mm], got {len(size)}: "
                                   f"{' '.join(str(v) for v in size)} (three, HX HY HZ, are a voxel mesh's)")
            object.__setattr__(self, "size", size[0] if len(size) == 1 else size)
        if self.kind == "voxel":
            if self.size is not None:
                object.__setattr__(self, "size", _one_or_three(check_sizes(self.size)))
        else:
            limits.check_length("volume mesh size", self.element_size)
        if self.gap is not None:
            limits.check_length("tet gap", self.gap)
        if self.yarn_vf is not None:
            check_yarn_vf(self.yarn_vf)
        if self.memory_limit is not None:
            limits.check_range("memory limit", self.memory_limit, 1e-6, limits.MAX_MEMORY_GB, " GB")
        if self.layers is not None:
            if self.kind != "voxel":
                raise TextileError("layers through the thickness are a voxel mesh's; a tet mesh takes its size only")
            limits.check_count("voxel layers", self.layers, 1, MAX_LAYERS)
        if not (np.isfinite(self.scale) and 0.1 <= self.scale <= 10):
            raise TextileError(f"volume mesh scale must be between 0.1 and 10, got {self.scale}")

    @property
    def scaled_layers(self) -> int | None:
        """The voxel layers asked, divided by the scale (at least one)."""
        return None if self.layers is None else max(1, round(self.layers / self.scale))


def _one_or_three(sizes: tuple[float, float, float]) -> float | tuple[float, ...]:
    """One size where the three are one (as given), else the three."""
    return sizes[0] if len(set(sizes)) == 1 else sizes


def fibre_fractions(textile: Textile, options: VolumeOptions) -> list[float]:
    """Each yarn's intra-yarn fibre volume fraction: options.yarn_vf, else the model's fibre data (the
    stated default where it has none). One above the densest packing of fibres is refused."""
    if options.yarn_vf is not None:
        return [options.yarn_vf] * len(textile.yarns)
    from textile_fenicsx.model.metrics import yarn_fibre_fractions

    vf, _ = yarn_fibre_fractions(textile)
    for y, v in zip(textile.yarns, vf):
        if v > HEXAGONAL:
            raise TextileError(f"{y.name}: its fibre data give an intra-yarn fibre volume fraction of {v:.3f}, above "
                               f"the densest packing of round fibres ({HEXAGONAL:.3f}); check its fibre data "
                               "(fibres per yarn, diameter, area, linear density, density) or give --yarn-vf")
    return vf


def refuse_sheared(textile: Textile) -> None:
    """A sheared cell (docs/shear.md) has no volume mesh yet, nor its homogenisation or permeability."""
    if textile.cell.shift:
        raise TextileError(f"{textile.name}: a sheared cell ({textile.cell.shear_angle:.4g} degrees) has no volume "
                           "mesh yet, so neither homogenisation nor permeability (docs/shear.md)")


def volume_mesh(textile: Textile, options: VolumeOptions = VolumeOptions(),
                comm: MPI.Comm = MPI.COMM_WORLD) -> VolumeMesh | None:
    """The periodic volume mesh of the textile (on rank 0; None on the other ranks). Collective:
    an error on rank 0 is raised on every rank."""
    refuse_sheared(textile)
    result, error = None, None
    if comm.rank == 0:
        try:
            vf = fibre_fractions(textile, options)
            if options.kind == "voxel":
                from textile_fenicsx.volume.voxel import voxel_mesh

                result = voxel_mesh(textile, cell_box(textile, options.z_range), options.voxel_sizes, vf,
                                    options.scaled_layers, options.scale)
            else:
                result = _tet(textile, options, vf)
        except (TextileError, MeshError) as e:
            error = e
    wait_asleep(comm)  # the other ranks leave rank 0's mesher (gmsh's threads) the cores
    error = comm.bcast(error, root=0)
    if error is not None:
        raise error
    return result


def _tet(textile: Textile, options: VolumeOptions, vf: list[float]) -> VolumeMesh:
    """The conforming tet mesh (volume.tet, on this rank) as a VolumeMesh."""
    from textile_fenicsx.volume.box import Box
    from textile_fenicsx.volume.tet.mesher import tet_mesh
    from textile_fenicsx.volume.tet.options import TetOptions

    tet = tet_mesh(textile, TetOptions(size=options.element_size * options.scale, gap=options.gap,
                                       z_range=options.z_range, memory_limit=options.memory_limit), MPI.COMM_SELF)
    assert tet is not None
    box = Box(tuple(float(v) for v in tet.lo), tuple(float(v) for v in tet.hi))
    yarn_vf = np.where(tet.phase > 0, np.asarray([0.0, *vf])[tet.phase], 0.0)
    report = dict(tet.report)
    report["yarns"] = [{"name": y["yarn"], "meshed_volume": y["meshed_mm3"], "model_volume": y["model_mm3"],
                        "relative_error": y["error_percent"] / 100} for y in report["volume"]["per_yarn"]]
    return VolumeMesh("tet", box, tet.points, tet.tets, tet.phase, tet.fibre, yarn_vf, tet.names[1:], report)


@dataclass(eq=False)
class CellMesh:
    """A meshed cell: the mesh arrays (on rank 0; None elsewhere), the same mesh distributed in DOLFINx
    with its phase tags and fields, and the mesher's report (every rank)."""

    mesh: VolumeMesh | None
    fields: VolumeFields
    report: dict[str, Any]

    def __repr__(self) -> str:
        r = self.report
        return f"CellMesh({r.get('kind')}, {r.get('elements')} elements, Vf {r.get('vf', float('nan')):.3f})"

    def write(self, out: str | Path, materials: dict[str, list[str]] | None = None) -> Path:
        """The volume mesh folder (README): volume.xdmf/.h5, .msh, .vtu, .inp, mesh_report.json; it
        appears only when complete (collective)."""
        from textile_fenicsx.common.files import staged_folder
        from textile_fenicsx.volume.files import FILES, write_volume

        with staged_folder(out, self.fields.mesh.comm, remove=FILES) as tmp:
            write_volume(self.mesh, self.fields, tmp, materials)
        return Path(out)


def mesh_cell(textile: Textile, options: VolumeOptions = VolumeOptions(),
              comm: MPI.Comm = MPI.COMM_WORLD) -> CellMesh:
    """The textile's periodic volume mesh, in DOLFINx too (collective)."""
    from textile_fenicsx.volume.files import report_document, to_dolfinx

    vm = volume_mesh(textile, options, comm)
    fields = to_dolfinx(vm, comm)
    report = comm.bcast(report_document(vm) if vm is not None else None, root=0)
    return CellMesh(vm, fields, report)
