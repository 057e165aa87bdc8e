"""The commands of the volume stage: `volume-mesh` (and `solve --volume-mesh`), `homogenise`; their
arguments are in arguments.py."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from textile_fenicsx.files import claim_output

if TYPE_CHECKING:
    from textile_fenicsx.volumes import VolumeOptions

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
    p.add_argument(f"--{prefix}size", type=float, default=0.2, metavar="H",
                   help="element size [mm] (default 0.2)")
    p.add_argument("--yarn-vf", type=float, metavar="V",
                   help="every yarn's intra-yarn fibre volume fraction, instead of the model's fibre data "
                   "(default: from the fibre data; 0.65 with a warning where there is none)")
    p.add_argument("--z-range", type=float, nargs=2, metavar=("ZMIN", "ZMAX"),
                   help="the cell through the thickness [mm] (default: the yarns' own extent)")


def options_from(args: argparse.Namespace, kind: str, size: float) -> VolumeOptions:
    """VolumeOptions from the parsed arguments (checked before any work)."""
    from textile_fenicsx.volumes import VolumeOptions

    return VolumeOptions(kind=kind, size=size, yarn_vf=args.yarn_vf,
                         z_range=tuple(args.z_range) if args.z_range else None,
                         memory_limit=getattr(args, "memory_limit", None))


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

    from textile_fenicsx.config import load_model
    from textile_fenicsx.volume_files import FILES
    from textile_fenicsx.volumes import mesh_cell

    comm = MPI.COMM_WORLD
    options = options_from(args, args.kind, args.size)
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
    "the conductivity K (W/(m K)), Vf, dofs, iterations, seconds; prints one line. Runs under mpirun.")


def homogenise(args: argparse.Namespace) -> int:
    from mpi4py import MPI

    from textile_fenicsx.api import homogenise as run_homogenise

    comm = MPI.COMM_WORLD
    from textile_fenicsx.homogenise import material

    material(args.fibre), material(args.matrix)  # a bad name or file is refused before any work
    with claim_output(args.out, inputs=[args.mesh], names=("stiffness.json",), force=True, comm=comm):
        result = run_homogenise(args.mesh, args.fibre, args.matrix, comm, degree=args.degree,
                                conduction=not args.no_conduction, memory_limit=args.memory_limit)
        result.write(args.out, comm)
    if comm.rank == 0:
        print(result.summary())
        print(Path(args.out) / "stiffness.json")
    return 0
