"""The commands of the volume stage: `volume-mesh` (and `solve --volume-mesh`), `homogenise`,
`permeability` (and `solve --permeability`); their arguments are in arguments.py."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.common.files import claim_output

if TYPE_CHECKING:
    from textile_fenicsx.flow.effective import PermeabilityOptions
    from textile_fenicsx.model.textile import Textile
    from textile_fenicsx.pipeline.stages import Run, Settings
    from textile_fenicsx.volume.stage import VolumeOptions

# what a volume mesh writes (volume_files.FILES, named here without importing DOLFINx)
FILES = ("volume.xdmf", "volume.h5", "volume.msh", "volume.vtu", "volume.inp", "mesh_report.json")
# what a permeability writes (Permeability.write: permeability.json and flow/files.py's FILES)
PERMEABILITY_FILES = ("permeability.json", "flow.xdmf", "flow.h5", "flow.vtu", "flow.png")

VOLUME_DESCRIPTION = (
    "Mesh the periodic cell of a model (a corrected one, or TexGen's idealised one) as volume elements, "
    "each matrix or exactly one yarn. voxel: N x N x M hexahedra, the phase read at each centre (a centre "
    "inside two yarns is counted and reported in mesh_report.json, and goes to the yarn it lies deepest "
    "in). tet: conforming tetrahedra (gmsh OpenCASCADE); a model whose yarns overlap is refused. The cell "
    "is the model's in plan and the yarns' own thickness (or --z-range). Writes DIR/volume.xdmf (+.h5: "
    "mesh, cell tags 'phase' = 0 matrix, 1 + i yarn i, DG0 fields 'direction' and 'yarn_vf'), "
    "DIR/volume.msh, DIR/volume.vtu, DIR/volume.inp (Abaqus: element sets, *Orientation per element) and "
    "DIR/mesh_report.json; the folder appears only when complete.")


def add_volume_options(p: argparse.ArgumentParser, prefix: str = "") -> None:
    """The volume mesh's options (on `volume-mesh`, and on `solve` with the prefix 'volume-')."""
    p.add_argument(f"--{prefix}size", type=float, nargs="+", metavar="H",
                   help="element size [mm]: H, or for voxels HX HY HZ, one per axis (default: tet 0.35; voxels "
                   "per axis from the yarns: 8 across the thinnest yarn's height, 12 across the narrowest yarn's "
                   "width, at most 60 000, docs/volume.md)")
    p.add_argument(f"--{prefix}layers", type=int, metavar="N",
                   help="voxel: N voxels through the thickness (default: the thickness over the size along z, "
                   "rounded)")
    p.add_argument("--yarn-vf", type=float, metavar="V",
                   help="every yarn's intra-yarn fibre volume fraction, instead of the model's fibre data "
                   "(on solve also the compaction law's relaxed fraction and the metrics' Vf; default: from the "
                   "fibre data; 0.65 with a warning where there is none)")
    if not prefix:
        p.add_argument("--z-range", type=float, nargs=2, metavar=("ZMIN", "ZMAX"),
                       help="the cell through the thickness [mm] (default: the yarns' own extent; tet: padded by "
                       "half the gap)")
        p.add_argument("--gap", type=float, metavar="G",
                       help="tet: the least gap between yarns the mesh is made for [mm] (default 5 %% of the "
                       "thinnest yarn's height; the model must hold 0.75 G: solve --min-gap G)")


def options_from(args: argparse.Namespace, kind: str, size: list[float] | None, layers: int | None = None,
                 flag: str = "--size") -> VolumeOptions:
    """VolumeOptions from the parsed arguments (checked before any work); size: `flag`'s values."""
    from textile_fenicsx.volume.stage import VolumeOptions

    if size is not None and len(size) not in ((1,) if kind == "tet" else (1, 3)):
        given = " ".join(f"{h:g}" for h in size)
        raise TextileError(f"{flag} takes one size H [mm] for a tet mesh, got {len(size)}: {given}" if kind == "tet"
                           else f"{flag} takes one size H or three HX HY HZ [mm], got {len(size)}: {given}")
    z_range = getattr(args, "z_range", None)
    return VolumeOptions(kind=kind, size=None if size is None else tuple(size), yarn_vf=args.yarn_vf,
                         z_range=tuple(z_range) if z_range else None, gap=getattr(args, "gap", None),
                         memory_limit=getattr(args, "memory_limit", None), layers=layers)


def solve_options(args: argparse.Namespace) -> VolumeOptions | None:
    """`solve --volume-mesh KIND`'s options (checked before the solve), or None."""
    if args.volume_mesh is None:
        return None
    if not args.out:
        raise TextileError("--volume-mesh needs --out DIR (the volume mesh's files go there)")
    return options_from(args, args.volume_mesh, args.volume_size, args.volume_layers, "--volume-size")


def flow_options(args: argparse.Namespace, volume: VolumeOptions | None) -> PermeabilityOptions | None:
    """`solve --permeability`'s options (checked before the solve), or None."""
    if not args.permeability:
        for flag, value in (("--yarn-permeability", args.yarn_permeability), ("--fibre-radius", args.fibre_radius)):
            if value is not None:
                raise TextileError(f"{flag} needs --permeability (with --volume-mesh voxel|tet)")
        return None
    if volume is None:
        raise TextileError("--permeability needs --volume-mesh voxel|tet: the permeability is that of the corrected "
                           "model's volume mesh")
    from textile_fenicsx.flow.effective import PermeabilityOptions

    return PermeabilityOptions(args.yarn_permeability or "gebart", args.fibre_radius,
                               memory_limit=getattr(args, "memory_limit", None))


def with_gap(settings: Settings, textile: Textile, volume: VolumeOptions | None,
             min_gap: float) -> tuple[Settings, VolumeOptions | None]:
    """The solve's settings and the volume options for a tet mesh: the gap the tet mesher needs (5 %
    of the input's thinnest yarn's height), or --min-gap where given, held by the contact solve (no
    yarn volume is lost) and the gap the mesh is then made for."""
    if volume is None or volume.kind != "tet":
        return settings, volume
    from textile_fenicsx.volume.tet.options import TetOptions, default_gap

    gap = min_gap if min_gap > 0 else default_gap(textile, TetOptions(gap=volume.gap))
    return replace(settings, solver=replace(settings.solver, min_gap=gap)), replace(volume, gap=gap)


def mesh_corrected(run: Run, options: VolumeOptions, out: str) -> Any:
    """The corrected model's volume mesh, into `out` beside the run's files; its cell through the
    thickness is the mould's cavity where the mould closed (else the yarns' own extent)."""
    from textile_fenicsx.volume.stage import mesh_cell

    if run.mould is not None and options.z_range is None:
        options = replace(options, z_range=(run.mould.bottom, run.mould.top))
    assert run.corrected is not None
    cell = mesh_cell(run.corrected, options, run.comm)
    cell.write(out)
    if run.comm.rank == 0:
        print(summary_line(cell.report))
    return cell


def permeability_corrected(run: Run, cell: Any, volume: VolumeOptions, flow: PermeabilityOptions, out: str) -> None:
    """`solve --permeability`: the permeability of the corrected model's volume mesh `cell`, into
    out/permeability.json; where the fabric was pressed (CompactionTarget.step_models) also at each
    point of the compaction curve, on voxel meshes of the volume mesh's size and layers (the last
    point's is the mesh's own where it is voxels), into out/compaction.json (K_m2) and compaction.png."""
    from textile_fenicsx.api import permeability_curve
    from textile_fenicsx.flow.effective import permeability
    from textile_fenicsx.pipeline.outputs import write_compaction

    comm = run.comm
    result = permeability(cell.fields, flow)
    result.write(out, comm)
    if comm.rank == 0:
        print(result.summary())
        print(Path(out) / "permeability.json")
    if run.step_models is None or run.compaction is None:
        return
    voxels = volume.kind == "voxel"
    curve = permeability_curve(run, flow.yarns, flow.fibre_radius, size=volume.size, layers=volume.layers, comm=comm,
                               last=result if voxels else None, memory_limit=flow.memory_limit)
    if comm.rank == 0:
        write_compaction(run, out)
        first, last = curve[0].K_m2, curve[-1].K_m2
        vf = run.compaction.vf
        print(f"permeability along the compaction curve ({len(curve)} points, voxels): Vf {vf[0]:.3f} -> "
              f"{vf[-1]:.3f}, Kxx {first[0, 0]:.4g} -> {last[0, 0]:.4g}, Kyy {first[1, 1]:.4g} -> {last[1, 1]:.4g}, "
              f"Kzz {first[2, 2]:.4g} -> {last[2, 2]:.4g} m^2 (compaction.json: K_m2)")
    comm.barrier()


def summary_line(report: dict) -> str:
    """One line on a volume mesh: kind, elements, Vf, the overlap and the worst yarn volume."""
    errors = [abs(y["relative_error"]) for y in report["yarns"] if y["relative_error"] is not None]
    overlap = report.get("overlap", {})
    text = (f"{report['kind']} mesh: {report['elements']} elements, Vf {report['vf']:.3f}, yarn volumes within "
            f"{100 * max(errors, default=0):.2f} % of the model's")
    if overlap.get("voxels"):
        text += f", {overlap['voxels']} voxels ({overlap['volume']:.3g} mm^3) in two yarns"
    return text


def volume_mesh(args: argparse.Namespace) -> int:
    from mpi4py import MPI

    from textile_fenicsx.io.config import load_model
    from textile_fenicsx.volume.files import FILES
    from textile_fenicsx.volume.stage import mesh_cell

    comm = MPI.COMM_WORLD
    options = options_from(args, args.kind, args.size, args.layers)
    textile = load_model(args.model)
    with claim_output(args.out, inputs=[args.model], names=FILES, force=args.force, comm=comm):
        cell = mesh_cell(textile, options, comm)
        cell.write(args.out)
    if comm.rank == 0:
        print(summary_line(cell.report))
        print(Path(args.out) / "volume.xdmf")
    return 0


HOMOGENISE_DESCRIPTION = (
    "Effective properties of a meshed periodic cell (MESH: the volume.xdmf that volume-mesh wrote): the six "
    "periodic cell problems of linear elasticity (fluctuation periodic through dolfinx_mpc's multi-point "
    "constraints, a unit mean strain each; second-order elements; CG + GAMG with the rigid-body near-null "
    "space) and the three of heat conduction. Yarns are transversely isotropic about their fibre direction, "
    "their constants from --fibre and --matrix at each element's fibre fraction by Chamis' micromechanics; "
    "the matrix is --matrix. Writes DIR/stiffness.json: C and S = C^-1 (6 x 6, MPa; Voigt order 11 22 33 "
    "23 13 12, engineering shear strains), Ex Ey Ez Gxy Gxz Gyz nuxy nuxz nuyz, the Voigt and Reuss bounds, "
    "the conductivity K (W/(m K)), Vf, dofs, iterations, seconds; prints one line. Given a model instead of a "
    "mesh, meshes it in voxels (the volume options) and again 1.5 x coarser, and adds each property's estimated "
    "discretisation error (Richardson, Roache's GCI: error_estimate); --accuracy P refines until within P %. "
    "Runs under mpirun.")


PERMEABILITY_DESCRIPTION = (
    "The permeability tensor of a meshed periodic cell: three Stokes-Brinkman cell problems (a unit mean "
    "pressure gradient along x, y and z; Stokes in the pores, Brinkman in the yarns with the fluid's viscosity; "
    "Taylor-Hood elements; periodic in x, y and z), K_ij = mu <u_i>. Writes DIR/permeability.json: K in m^2 and "
    "mm^2, its principal values and directions, the cell's Vf and porosity, dofs, seconds, checks; the flow of "
    "each load case, velocity_x [mm/s] and pressure_x [Pa] (its periodic part) etc. for ParaView: DIR/flow.xdmf "
    "(+.h5; at the vertices, the velocity interpolated into P1) and DIR/flow.vtu (at every node of the P2 velocity, "
    "quadratic cells); DIR/flow.png, the velocity magnitude on cuts. The files appear together when all are "
    "written. Gebart's laws are an upper bound for random packings; the flow is slow (Stokes).")


MODEL_SUFFIXES = (".tg3", ".toml", ".json")


def model_volume(args: argparse.Namespace, command: str) -> tuple[VolumeOptions | None, float | None]:
    """The voxel mesh's options where `command` was given a model to mesh (None for a mesh), and the
    accuracy asked as a fraction; options that need a model are refused on a mesh (before any work)."""
    if args.accuracy is not None and not 0 < args.accuracy < 100:
        raise TextileError(f"--accuracy is a percentage between 0 and 100, got {args.accuracy:g}")
    accuracy = None if args.accuracy is None else args.accuracy / 100
    if Path(args.mesh).suffix.lower() in MODEL_SUFFIXES:
        return options_from(args, "voxel", args.size, args.layers), accuracy
    given = [flag for flag, value in (("--accuracy", args.accuracy), ("--size", args.size), ("--layers", args.layers),
                                      ("--yarn-vf", args.yarn_vf), ("--z-range", args.z_range), ("--gap", args.gap))
             if value is not None]
    if given:
        raise TextileError(f"{', '.join(given)} need a model ({', '.join(MODEL_SUFFIXES)}) to mesh, not the mesh "
                           f"{args.mesh}: give {command} the model file")
    return None, accuracy


def _finish(result: Any, out: Path, accuracy: float | None, comm: Any) -> int:
    """Print the result's summary line and file; exit 1 where the accuracy asked was not reached."""
    if comm.rank == 0:
        print(result.summary())
        print(out)
    if result.error is None or result.error["accuracy_met"]:
        return 0
    if comm.rank == 0:
        worst = max(result.error["quantities"].items(), key=lambda q: q[1]["relative_error"])
        print(f"textile-fenicsx: error: accuracy {100 * (accuracy or 0):g} % not reached: {worst[0]}'s estimated "
              f"error is {100 * worst[1]['relative_error']:.2g} % after {len(result.error['meshes'])} meshes "
              f"({result.error['stopped']}); {out.name} holds the finest mesh's values and their estimate. Ask a "
              "larger --accuracy, or give --memory-limit where the memory guard stopped it", file=sys.stderr)
    return 1


def permeability(args: argparse.Namespace) -> int:
    from mpi4py import MPI

    from textile_fenicsx.api import permeability as run_permeability
    from textile_fenicsx.api import permeability_model
    from textile_fenicsx.flow.effective import PermeabilityOptions

    comm = MPI.COMM_WORLD
    PermeabilityOptions(args.yarn_permeability, args.fibre_radius, args.degree, solver=args.solver)  # refused early
    volume, accuracy = model_volume(args, "permeability")
    settings = dict(degree=args.degree, memory_limit=args.memory_limit, solver=args.solver)
    with claim_output(args.out, inputs=[args.mesh], names=PERMEABILITY_FILES, force=True, comm=comm):
        if volume is not None:
            result = permeability_model(args.mesh, volume, args.yarn_permeability, args.fibre_radius, comm, accuracy,
                                        **settings)
        else:
            result = run_permeability(args.mesh, args.yarn_permeability, args.fibre_radius, comm, **settings)
        result.write(args.out, comm)
    return _finish(result, Path(args.out) / "permeability.json", accuracy, comm)


def homogenise(args: argparse.Namespace) -> int:
    from mpi4py import MPI

    from textile_fenicsx.api import homogenise as run_homogenise
    from textile_fenicsx.api import homogenise_model
    from textile_fenicsx.homogenisation import material

    comm = MPI.COMM_WORLD
    material(args.fibre), material(args.matrix)  # a bad name or file is refused before any work
    volume, accuracy = model_volume(args, "homogenise")
    settings = dict(degree=args.degree, conduction=not args.no_conduction, memory_limit=args.memory_limit)
    with claim_output(args.out, inputs=[args.mesh], names=("stiffness.json",), force=True, comm=comm):
        if volume is not None:
            result = homogenise_model(args.mesh, volume, args.fibre, args.matrix, comm, accuracy, **settings)
        else:
            result = run_homogenise(args.mesh, args.fibre, args.matrix, comm, **settings)
        result.write(args.out, comm)
    return _finish(result, Path(args.out) / "stiffness.json", accuracy, comm)
