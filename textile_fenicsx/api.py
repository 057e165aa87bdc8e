"""The one-call interface (what `import textile_fenicsx as tfx` offers):

    import textile_fenicsx as tfx
    textile = tfx.read("satin4.tg3")          # or tfx.build("crowfoot_satin", spacing=2.8, ...)
    run = tfx.solve(textile, seed=0.5)         # mesh, contact solve, corrected textile
    run.corrected, run.metrics, run.verdict    # the corrected model, its numbers, its check
    run.write("out/")                          # the output folder (docs/usage.md: "The output folder")
    cell = tfx.volume_mesh(run.corrected, kind="voxel")             # the periodic volume mesh
    result = tfx.homogenise(cell, fibre="e-glass", matrix="epoxy")  # C, S, constants, K
    cell.write("out/volume"), result.write("out/volume")
    k = tfx.permeability(cell, fibre_radius=0.0035)                   # Stokes-Brinkman: K [mm^2], K_m2

Every call is collective under MPI (run the script with mpirun); progress goes to the
`textile_fenicsx` logger (`tfx.show_progress()` prints it from rank 0).
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from textile_fenicsx.flow.effective import Permeability
    from textile_fenicsx.homogenisation import Homogenised
    from textile_fenicsx.model.textile import Textile
    from textile_fenicsx.pipeline.stages import Run
    from textile_fenicsx.volume.stage import CellMesh

__all__ = ["build", "homogenise", "homogenise_model", "permeability", "permeability_curve", "permeability_model",
           "read", "show_progress", "solve", "volume_mesh"]


def read(path) -> Textile:
    """A textile model from a file: TexGen .tg3, or our .toml / .json (config.py documents them)."""
    from textile_fenicsx.io.config import load_model

    return load_model(Path(path))


def build(name: str, **sizes) -> Textile:
    """An idealised unit cell from a builder: plain, twill, satin, crowfoot_satin, basket (2D weaves:
    spacing, width, height, thickness [mm], ...) or orthogonal (3D; weaves.py lists the options)."""
    from textile_fenicsx.model.weaves import build as _build

    return _build(name, **sizes)


def solve(textile, seed: float = 0.5, method: str = "exact", repeat: tuple[int, int] | None = None,
          free_edges: bool = False, comm=None, **settings) -> Run:
    """Correct a textile: its projected mesh at element size `seed` [mm], the plates' contact
    solve (`method` "exact" or the paper's "penalty"), the corrected textile and its check (measured
    in the run, which meshes again where it finds overlaps, `remesh`; with remesh=0 on first use of
    `run.metrics`). `repeat=(nx, ny)`: a coupon of nx x ny cells (with free edges if
    asked). Other settings by name: `plate=PlateParameters(...)`, `mesh=MeshOptions(...)`,
    `solver=SolverOptions(...)`, `correction=CorrectionOptions(...)` (replacing seed/method)."""
    from mpi4py import MPI

    from textile_fenicsx.pipeline.stages import Settings, run
    from textile_fenicsx.plate.mesh.projected import MeshOptions
    from textile_fenicsx.plate.solver import SolverOptions

    if repeat is not None:
        from textile_fenicsx.model.coupon import tile

        textile = tile(textile, *repeat, free_edges=free_edges)
    settings.setdefault("mesh", MeshOptions(seed))
    settings.setdefault("solver", SolverOptions(method=method))
    return run(textile, Settings(**settings), comm or MPI.COMM_WORLD)


def volume_mesh(textile, kind: str = "voxel", size: float | tuple[float, ...] | None = None, comm=None,
                **options) -> CellMesh:
    """The periodic volume mesh of a model (a Textile, or a model file's path): `kind` "voxel" or
    "tet", element size `size` [mm]: H, or for voxels (HX, HY, HZ) (default: tet 0.35; voxel per
    axis from the yarns' heights and widths, volume.voxel.default_grid); other VolumeOptions by name
    (yarn_vf, z_range, memory_limit, layers, and for tet the TetOptions' own). `.write(folder)`
    writes its files."""
    from mpi4py import MPI

    from textile_fenicsx.volume.stage import VolumeOptions, mesh_cell

    if not hasattr(textile, "yarns"):
        textile = read(textile)
    return mesh_cell(textile, VolumeOptions(kind, size, **options), comm or MPI.COMM_WORLD)


def homogenise(volume, fibre="e-glass", matrix="epoxy", comm=None, **options) -> Homogenised:
    """Effective stiffness and conductivity of a meshed cell (what `volume_mesh` returns, or the
    path of a volume.xdmf it wrote): the six periodic elastic cell problems and three thermal
    ones, yarns transversely isotropic by Chamis' micromechanics from `fibre` and `matrix` (preset
    names: e-glass, t300, epoxy; or TOML files). Other HomogeniseOptions by name. `.write(folder)`
    writes stiffness.json."""
    from mpi4py import MPI

    from textile_fenicsx.homogenisation import HomogeniseOptions
    from textile_fenicsx.homogenisation import homogenise as _homogenise
    from textile_fenicsx.volume.files import read_volume

    fields = getattr(volume, "fields", None)
    if fields is None:
        fields = read_volume(volume, comm or MPI.COMM_WORLD)
    return _homogenise(fields.mesh, fields.phase, fields.direction, fields.yarn_vf, fibre, matrix,
                       HomogeniseOptions(**options))


def homogenise_model(textile, volume=None, fibre="e-glass", matrix="epoxy", comm=None, accuracy: float | None = None,
                     **options) -> Homogenised:
    """Homogenise a model (a Textile or a model file's path) with the error of its properties: it
    is meshed by `volume` (VolumeOptions; default voxels at the default sizes) and by meshes RATIO
    times coarser and, with an `accuracy` asked (a fraction, e.g. 0.01), finer ones until every
    engineering constant's and conductivity's estimated error is within it
    (volume/refinement.py). The result is the finest mesh's, its `.error` the estimate, written
    to stiffness.json's "error_estimate". Other HomogeniseOptions by name."""
    from mpi4py import MPI

    from textile_fenicsx.homogenisation import HomogeniseOptions
    from textile_fenicsx.homogenisation.estimate import homogenise_model as _homogenise_model
    from textile_fenicsx.volume.stage import VolumeOptions

    if not hasattr(textile, "yarns"):
        textile = read(textile)
    return _homogenise_model(textile, volume or VolumeOptions(), fibre, matrix, HomogeniseOptions(**options),
                             accuracy, comm or MPI.COMM_WORLD)


def permeability(volume, yarns="gebart", fibre_radius=None, comm=None, **options):
    """The permeability tensor of a meshed cell (what `volume_mesh` returns, or the path of a
    volume.xdmf it wrote): three periodic Stokes-Brinkman cell problems. yarns: "gebart" (Gebart's
    laws at each element's fibre fraction and direction, with the fibre radius `fibre_radius` [mm]),
    "impermeable" or a permeability [m^2]. Other PermeabilityOptions by name. Returns a
    Permeability: `.K` [mm^2], `.K_m2`, `.summary()`, `.write(folder)` (permeability.json, and
    the flow's flow.xdmf, flow.vtu, flow.png)."""
    from mpi4py import MPI

    from textile_fenicsx.flow.effective import PermeabilityOptions
    from textile_fenicsx.flow.effective import permeability as _permeability
    from textile_fenicsx.volume.files import read_volume

    fields = getattr(volume, "fields", None)
    if fields is None:
        fields = read_volume(volume, comm or MPI.COMM_WORLD)
    return _permeability(fields, PermeabilityOptions(yarns=yarns, fibre_radius=fibre_radius, **options))


def permeability_model(textile, volume=None, yarns="gebart", fibre_radius=None, comm=None,
                       accuracy: float | None = None, **options) -> Permeability:
    """The permeability of a model (a Textile or a model file's path) with the error of Kxx, Kyy and
    Kzz: it is meshed in voxels by `volume` (VolumeOptions; default the voxel rule) and RATIO times
    coarser and, with an `accuracy` asked (a fraction), finer until within it (volume/refinement.py).
    The finest mesh's result, its `.error` the estimate, written to permeability.json's
    "error_estimate". yarns, fibre_radius and other PermeabilityOptions as `permeability`'s."""
    from mpi4py import MPI

    from textile_fenicsx.flow.effective import PermeabilityOptions
    from textile_fenicsx.flow.estimate import permeability_model as _permeability_model
    from textile_fenicsx.volume.stage import VolumeOptions

    if not hasattr(textile, "yarns"):
        textile = read(textile)
    return _permeability_model(textile, volume or VolumeOptions(),
                               PermeabilityOptions(yarns=yarns, fibre_radius=fibre_radius, **options), accuracy,
                               comm or MPI.COMM_WORLD)


def permeability_curve(run: Run, yarns="gebart", fibre_radius=None, size: float | tuple[float, ...] | None = None,
                       layers: int | None = None, comm=None, last: Permeability | None = None,
                       memory_limit: float | None = None) -> list[Permeability]:
    """The permeability at each point of a run's compaction curve (a run solved with
    `compaction=CompactionTarget(..., step_models=True)`): each point's corrected model meshed in
    voxels of `size` [mm] in plan (H or (HX, HY, HZ); default the voxel rule's sizes of the last
    point, the thinnest, as its volume mesh has them) and `layers` through its platens' cavity (the
    relaxed fabric: its yarns' own extent), the same grid at every point (default: the layers the
    size along z gives the last point), then the three flow cell problems (`permeability`; `yarns`
    and `fibre_radius` as there). `last`: the last point's, where it is known already (its voxel
    mesh of that size). Fills `run.compaction.K_m2` [m^2]; returns one Permeability per point, in
    order."""
    import logging

    import numpy as np
    from mpi4py import MPI

    from textile_fenicsx.common.errors import TextileError
    from textile_fenicsx.volume.box import cell_box
    from textile_fenicsx.volume.voxel import default_grid, voxel_counts

    if run.compaction is None or run.step_models is None:
        raise TextileError("the permeability along a compaction curve needs a run pressed with "
                           "CompactionTarget(step_models=True)")
    comm = comm or MPI.COMM_WORLD
    log = logging.getLogger("textile_fenicsx.api")
    cavities = [None if mould is None else (mould.bottom, mould.top) for _, mould in run.step_models]
    if size is None or layers is None:
        box = cell_box(run.step_models[-1][0], cavities[-1])
        if size is None:  # the last point's default grid, as its volume mesh has it
            size = tuple(float(v) for v in box.size / np.array(default_grid(run.step_models[-1][0], box, layers)[0]))
        if layers is None:
            layers = voxel_counts(box, size)[2]
    results = []
    for i, ((model, _), z_range) in enumerate(zip(run.step_models, cavities)):
        if last is not None and i == len(run.step_models) - 1:
            result = last
        else:
            cell = volume_mesh(model, "voxel", size, comm, z_range=z_range, layers=layers, memory_limit=memory_limit)
            result = permeability(cell, yarns, fibre_radius, comm, memory_limit=memory_limit)
        results.append(result)
        log.info("compaction point %d of %d: Vf %.3f (the voxels' %.3f): %s", i + 1, len(run.step_models),
                 run.compaction.vf[i], result.vf, result.summary())
    run.compaction.K_m2 = [r.K_m2.tolist() for r in results]
    return results


def show_progress(level: int = logging.INFO, stream=None) -> None:
    """Print the library's progress lines (mesh, contact steps, outputs) from MPI rank 0."""
    from mpi4py import MPI

    root = logging.getLogger("textile_fenicsx")
    root.handlers.clear()
    root.propagate = False
    if MPI.COMM_WORLD.rank == 0:
        handler = logging.StreamHandler(stream or sys.stderr)
        handler.setFormatter(logging.Formatter("%(message)s"))
        root.addHandler(handler)
        root.setLevel(level)
    else:
        root.addHandler(logging.NullHandler())
