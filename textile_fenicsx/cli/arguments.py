"""The `textile-fenicsx` command line's arguments: one parser per command, each with its help."""

import argparse

from textile_fenicsx.cli import commands, volume_commands
from textile_fenicsx.version import __version__

__all__ = ["build_parser"]

Subparsers = argparse._SubParsersAction  # what add_subparsers returns


def _repeat_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--repeat", type=int, nargs=2, metavar=("NX", "NY"),
                   help="solve a coupon of NX x NY unit cells as one periodic cell (yarns continued across)")
    p.add_argument("--free-edges", action="store_true",
                   help="with --repeat: cut the coupon out of the fabric instead; its sides are the yarns' "
                        "free ends (edge effects)")


def _mesh_arguments(p: argparse.ArgumentParser) -> None:
    """The projected-mesh options shared by `mesh` and `solve`."""
    p.add_argument("--seed", type=float, default=0.5, help="element size [mm] (default 0.5)")
    p.add_argument("--sliver", type=float, help="merge yarn edges closer than this [mm] (default seed/20)")
    p.add_argument("--max-slope", type=float, default=10.0,
                   help="steepest yarn slope accepted (default 10: 84 degrees)")
    p.add_argument("--allow-steep", action="store_true", help="warn about too-steep yarns instead of stopping")
    p.add_argument("--memory-limit", type=float, metavar="GB",
                   help="refuse seeds whose run would need more memory than this (default: what is available)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="textile-fenicsx",
        description="Predict the real geometry of a woven textile unit cell: the yarns' mid-surfaces "
        "are plates that minimise bending + tension + contact energy (Lin et al. 2012), solved "
        "with FEniCSx. Lengths in mm.",
        epilog="From a checkout, run it through the project's environment: "
        "bin/fenicsx-env textile-fenicsx COMMAND ... Exit codes: 0 success, 1 the run failed (no convergence, "
        "singular or non-finite solve, a file that cannot be written), 2 bad input or usage, 130 interrupted "
        "(no output written).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    subparsers = parser.add_subparsers(title="commands", metavar="COMMAND")
    _versions_command(subparsers)
    _report_command(subparsers)
    _build_command(subparsers)
    _mesh_command(subparsers)
    _solve_command(subparsers)
    _volume_mesh_command(subparsers)
    _homogenise_command(subparsers)
    _permeability_command(subparsers)
    return parser


def _versions_command(subparsers: Subparsers) -> None:
    """`versions`: the numerical stack's versions."""
    p = subparsers.add_parser("versions", help="print the versions of the numerical stack")
    p.set_defaults(run=commands.versions)


def _report_command(subparsers: Subparsers) -> None:
    """`report MODEL`: a model's metrics as JSON."""
    p = subparsers.add_parser(
        "report", help="print the metrics of a model as JSON",
        description="Measure a model (.tg3 from TexGen, or our .toml/.json) on an N x N grid of vertical "
        "rays: yarn volumes, interpenetration volume and depth (total and per yarn pair), thickness, "
        "crimp per yarn, fibre volume fraction (null without fibre data). mm and mm^3.")
    p.add_argument("model", help="model file: .tg3, .toml or .json")
    p.add_argument("--grid", type=int, default=200, metavar="N",
                   help="rays per cell side (default 200, as the reference measurements)")
    p.set_defaults(run=commands.report)


def _plies_arguments(p: argparse.ArgumentParser) -> None:
    """--plies N, --ply-offsets, --ply-seed (solve, build)."""
    p.add_argument("--plies", type=int, default=1, metavar="N",
                   help="stack N plies of the fabric in one cell, ply k moved by its offset in the plane and by k "
                   "times the fabric's thickness up; they nest by the same contact solve (docs/compaction.md)")
    p.add_argument("--ply-offsets", nargs="+", metavar="DX,DY",
                   help="with --plies N: the N plies' in-plane offsets [mm] (default: random in the cell, "
                   "--ply-seed; the first ply in place)")
    p.add_argument("--ply-seed", type=int, default=0, metavar="S", help="with --plies: the random offsets' seed (0)")


def _build_command(subparsers: Subparsers) -> None:
    """`build NAME`: a named weave written as model, surfaces and picture."""
    p = subparsers.add_parser(
        "build", help="build a named weave and write its model, surfaces and picture",
        description="Build an idealised unit cell and write DIR/NAME.json (our model), DIR/NAME.tg3 "
        "(TexGen), DIR/NAME.vtu and DIR/NAME.stl (yarn surfaces clipped to the cell, yarn index as cell "
        "data in the VTU) and DIR/NAME.png. Files appear only when all are written.")
    p.add_argument("name", choices=["plain", "twill", "satin", "crowfoot_satin", "orthogonal"],
                   help="weave: 2D plain, twill, satin, crowfoot_satin (4-harness), or 3D orthogonal")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    for name, kind, text in (("spacing", float, "yarn spacing [mm] (2D weaves)"),
                             ("width", float, "yarn width [mm] (2D weaves)"),
                             ("height", float, "yarn height [mm] (2D weaves)"),
                             ("thickness", float, "fabric thickness [mm] (2D weaves; default sum of heights)"),
                             ("power", float, "section power: power-ellipse sections (2D weaves)"),
                             ("over", int, "twill: wefts each warp floats over"),
                             ("under", int, "twill: wefts each warp passes under"),
                             ("harness", int, "satin: harness number (>= 5)"),
                             ("move", int, "satin: move number, coprime with the harness")):
        p.add_argument(f"--{name}", type=kind, help=text)
    p.add_argument("--allow-overlap", action="store_true", help="accept widths larger than spacings")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="any other builder option, e.g. --set weft_width=2.2 (orthogonal: warp_*, weft_*, "
                   "binder_* spacing/width/height/power, warp_layers, n_warp_stacks, n_weft_columns)")
    _plies_arguments(p)
    _repeat_argument(p)
    p.add_argument("--no-picture", action="store_true", help="skip the PNG")
    p.set_defaults(run=commands.build)


def _mesh_command(subparsers: Subparsers) -> None:
    """`mesh MODEL`: the projected mesh and its statistics."""
    p = subparsers.add_parser(
        "mesh", help="mesh a model's projected regions and print mesh statistics as JSON",
        description="Mesh the unit cell by the sets of yarns covering it (gmsh; periodic sides; element "
        "size = seed) and sample each yarn's mid-surface, as `solve` does: a yarn's steep stretches (a "
        "binder's legs) are cut out first and its crowns meshed as plates of their own. Prints JSON: cells, "
        "nodes, dofs per yarn (per crown), minimum angle, footprint area per yarn (mesh vs model), "
        "thickness integral vs yarn volume, contact pairs, the yarns whose legs were cut, time. With "
        "--out, writes DIR/mesh.xdmf (+.h5, cell tags = covering set), DIR/mesh.json and DIR/mesh.png. "
        "Runs under mpirun.")
    p.add_argument("model", help="model file: .tg3, .toml or .json")
    p.add_argument("--out", metavar="DIR", help="write mesh.xdmf, mesh.json and mesh.png there")
    p.add_argument("--force", action="store_true",
                   help="allow --out to be the model's own folder (the model file itself is never replaced)")
    _mesh_arguments(p)
    _repeat_argument(p)
    p.add_argument("--no-picture", action="store_true", help="skip the PNG")
    p.set_defaults(run=commands.mesh)


def _solve_command(subparsers: Subparsers) -> None:
    """`solve INPUT`: the whole correction."""
    p = subparsers.add_parser(
        "solve", help="correct a model: mesh, then minimise bending + tension + contact energy",
        description="Run the whole path on INPUT (a .tg3, our .toml/.json, or a named weave: plain, twill, "
        "satin, crowfoot_satin, orthogonal): projected mesh, mid-surfaces, then the contact iteration, "
        "logging one line per iteration on stderr (max penetration, move, step, time). Prints a summary line "
        "(the check's verdict, interpenetration and thickness before -> after, dofs, steps, time), and with "
        "--json the numbers as JSON (metrics.json with --out, else the run's summary). With --out DIR "
        "writes DIR/corrected.tg3, DIR/corrected.json, DIR/initial.json, DIR/metrics.json (before/after), "
        "DIR/fields/yarn_I.vtu (w, z0, t, z, gap_below, contact at the mid-surface's vertices), "
        "DIR/surfaces_{before,after}.{vtu,stl} and figures DIR/view_{before,after}.png, DIR/cross_sections.png; "
        "the folder appears only when complete, and earlier results in it are replaced. DIR is checked before the "
        "solve (not an existing file, writable, not the input's folder without --force) and one run at a time "
        "writes it (a second run into DIR fails at once). "
        "If the contact iteration does not converge, DIR holds only FAILED (the reason) and log.json "
        "(the iteration log) and the exit code is 1. Exit codes: 0 done, 1 the run failed, 2 bad input, "
        "130 interrupted (no output written).")
    p.add_argument("input", help="model file or named weave")
    p.add_argument("--shear", type=float, metavar="DEG",
                   help="a named 2D weave sheared by DEG degrees: its wefts turn from y toward x at fixed spacings "
                   "along the yarns, as TexGen's CShearedTextileWeave2D (refused at or beyond the angle where the "
                   "yarns jam; docs/shear.md)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="a named weave's builder option, e.g. --set width=1.4 (as build's --set)")
    p.add_argument("--out", metavar="DIR", help="write the corrected model, metrics, fields, surfaces, figures")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--json", action="store_true",
                   help="also print the numbers as JSON on stdout (metrics.json with --out, else the run's summary)")
    p.add_argument("--force", action="store_true",
                   help="allow --out to be the input's own folder (the input file itself is never replaced)")
    _mesh_arguments(p)
    _repeat_argument(p)
    p.add_argument("--db1", type=float, default=1.0, help="bending stiffness along the fibre [N mm] (1)")
    p.add_argument("--db2", type=float, default=1.0, help="bending stiffness across the fibre [N mm] (1)")
    p.add_argument("--db12", type=float, default=None, help="twisting stiffness [N mm] (default (Db1+Db2)/4)")
    p.add_argument("--sigma1", type=float, default=1.0, help="fibre tension [N/mm] (1)")
    p.add_argument("--ec", type=float, default=1e3, help="contact stiffness where yarns penetrate [N/mm^3] (1e3)")
    p.add_argument("--et", type=float, default=1e-4, help="contact stiffness where yarns are apart [N/mm^3] (1e-4)")
    p.add_argument("--method", choices=["exact", "penalty"], default="exact",
                   help="exact (default: no penetration at the mesh nodes, to --penetration-tol) or penalty "
                   "(the paper's: contact stiffness --ec, some penetration remains)")
    p.add_argument("--penetration-tol", type=float, default=1e-6,
                   help="exact method: penetration and complementarity tolerance at the nodes [mm] (1e-6)")
    p.add_argument("--max-iterations", type=int, default=100, help="cap on contact iterations (100)")
    p.add_argument("--remesh", type=int, default=2, metavar="N",
                   help="exact method: where the corrected yarns overlap and nothing else fails the check, or the "
                   "contact iteration reaches its cap, mesh again with the seed x 0.7 and solve again, up to N "
                   "times (2; 0: never; not weaves with binder legs)")
    p.add_argument("--volume-mesh", choices=["voxel", "tet"], metavar="KIND",
                   help="then mesh the corrected model's periodic cell with volume elements (voxel or tet: the files "
                   "of volume-mesh, in DIR)")
    volume_commands.add_volume_options(p, prefix="volume-")
    p.add_argument("--permeability", action="store_true",
                   help="then the permeability tensor of that volume mesh (the permeability command's flow cell "
                   "problems; DIR/permeability.json); with --compaction also at each point of the curve, on voxel "
                   "meshes of --volume-size and --volume-layers (compaction.json: K_m2; compaction.png: K against Vf)")
    p.add_argument("--yarn-permeability", type=_yarn_permeability, metavar="gebart|impermeable|K",
                   help="with --permeability: the yarns' (as the permeability command's; default gebart)")
    p.add_argument("--fibre-radius", type=float, metavar="MM",
                   help="with --permeability: the fibres' radius for Gebart's laws [mm] (default 0.0035, with a "
                   "warning)")
    p.add_argument("--min-gap", type=float, default=0.0, metavar="G",
                   help="exact method: keep yarns in contact (and a mould's platens) at least G mm apart, their "
                   "sections unchanged (default 0: they touch); a tet mesh needs a gap (--volume-mesh tet sets "
                   "G to 5 %% of the thinnest yarn's height unless given)")
    p.add_argument("--out-of-core", action="store_true",
                   help="MUMPS keeps its factors on disk ($MUMPS_OOC_TMPDIR, else /tmp): less memory for large "
                   "coupons (docs/performance.md), somewhat slower")
    p.add_argument("--mould", type=_mould, default="auto", metavar="auto|none|T",
                   help="solve the fabric in a mould of thickness T [mm], its cavity centred on the model's "
                   "mid-plane, closing only on a fabric that comes out thicker (exact method); auto (default): "
                   "the thickness a 3D weave is woven to (TexGen's FabricThickness), made room in with a warning "
                   "where its yarns stack thicker (DESIGN.md 5), none for other fabrics")
    _plies_arguments(p)
    p.add_argument("--compaction", type=float, metavar="K",
                   help="press the relaxed fabric further, its yarns flattening by Van Wyk's law p = K (phi^3 - "
                   "phi0^3), K = k E_f [MPa]: to --mould T (now also below the relaxed stack) or to --vf V "
                   "(docs/compaction.md); writes compaction.json and compaction.png")
    p.add_argument("--vf", type=float, metavar="V",
                   help="with --compaction: press to the fibre volume fraction V [-] (the fibres' volume from the "
                   "model's fibre data, or a yarn fibre fraction of 0.65 where it has none)")
    p.add_argument("--compaction-steps", type=int, default=4, metavar="N",
                   help="with --compaction: the platens close in N equal steps, one point of the curve each (4)")
    p.add_argument("--max-packing", type=float, default=0.9069, metavar="PHI",
                   help="with --compaction: the largest fibre fraction a yarn may reach [-] (0.9069, hexagonal)")
    p.add_argument("--spreading", type=float, default=0.0, metavar="S",
                   help="with --compaction: a yarn pressed to r of its volume widens by r^-S into the room beside "
                   "it, and the fabric is solved and pressed again until the widths settle (0: widths kept, the "
                   "default; 1: sections keep their area; docs/compaction.md)")
    p.set_defaults(run=commands.solve)


def _mould(text: str) -> str | float | None:
    """--mould's value: "auto", None ("none") or a thickness [mm]."""
    if text in ("auto", "none"):
        return None if text == "none" else text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, none or a thickness in mm, got {text!r}") from None


def _volume_mesh_command(subparsers: Subparsers) -> None:
    """`volume-mesh`: the periodic volume mesh of a model's cell."""
    p = subparsers.add_parser("volume-mesh", help="mesh a model's periodic cell with volume elements",
                              description=volume_commands.VOLUME_DESCRIPTION)
    p.add_argument("model", help="model file: .tg3, .toml or .json")
    p.add_argument("--kind", choices=["voxel", "tet"], required=True, help="voxel hexahedra or conforming tetrahedra")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    p.add_argument("--force", action="store_true",
                   help="allow --out to be the model's own folder (the model file itself is never replaced)")
    volume_commands.add_volume_options(p)
    p.add_argument("--memory-limit", type=float, metavar="GB",
                   help="refuse sizes whose mesh would need more memory than this (default: what is available)")
    p.set_defaults(run=volume_commands.volume_mesh)


def _mesh_or_model(p: argparse.ArgumentParser) -> None:
    """MESH (a volume.xdmf, or a model to mesh in voxels with the error estimate), the volume
    options and --accuracy (homogenise, permeability)."""
    p.add_argument("mesh", help="the volume mesh: volume.xdmf written by volume-mesh (with its .h5); or a model "
                   "(.tg3, .toml, .json), meshed here in voxels by the volume options, with the error estimate")
    volume_commands.add_volume_options(p)
    p.add_argument("--accuracy", type=float, metavar="PERCENT",
                   help="with a model: refine the mesh until every property's estimated error is within PERCENT %% "
                   "(default: the mesh asked and one coarser, for the estimate)")


def _homogenise_command(subparsers: Subparsers) -> None:
    """`homogenise`: the effective stiffness and conductivity of a meshed cell."""
    p = subparsers.add_parser("homogenise", help="effective stiffness and conductivity of a meshed periodic cell",
                              description=volume_commands.HOMOGENISE_DESCRIPTION)
    _mesh_or_model(p)
    p.add_argument("--fibre", default="e-glass", metavar="NAME|FILE",
                   help="fibre material: e-glass (default), t300, or a TOML file (isotropic E, nu or transversely "
                   "isotropic E1 E2 G12 nu12 G23; conductivities k or k1 k2)")
    p.add_argument("--matrix", default="epoxy", metavar="NAME|FILE",
                   help="matrix material: epoxy (default) or a TOML file (isotropic E, nu, k)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder for stiffness.json (created if missing)")
    p.add_argument("--degree", type=int, default=2, choices=[1, 2],
                   help="Lagrange degree of the cell problems (default 2: P2 on tetrahedra, Q2 on hexahedra)")
    p.add_argument("--no-conduction", action="store_true", help="skip the thermal cell problems")
    p.add_argument("--memory-limit", type=float, metavar="GB",
                   help="refuse a mesh whose cell problems would need more memory than this (default: what is "
                   "available)")
    p.set_defaults(run=volume_commands.homogenise)


def _yarn_permeability(text: str) -> str | float:
    """--yarn-permeability: gebart, impermeable or a positive number of m^2."""
    if text in ("gebart", "impermeable"):
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be gebart, impermeable or a permeability in m^2, not "
                                         f"{text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"a permeability must be a positive number of m^2, not {text!r}")
    return value


def _permeability_command(subparsers: Subparsers) -> None:
    """`permeability`: the permeability tensor of a meshed cell."""
    p = subparsers.add_parser("permeability", help="permeability tensor of a meshed periodic cell (Stokes-Brinkman)",
                              description=volume_commands.PERMEABILITY_DESCRIPTION)
    _mesh_or_model(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder for permeability.json and the flow's "
                   "files (created if missing)")
    p.add_argument("--yarn-permeability", type=_yarn_permeability, default="gebart", metavar="gebart|impermeable|K",
                   help="the yarns: Gebart's laws at each element's fibre fraction and direction (default), solid "
                   "(impermeable: no-slip on their surfaces), or an isotropic permeability K in m^2")
    p.add_argument("--fibre-radius", type=float, metavar="MM",
                   help="the fibres' radius for Gebart's laws [mm] (default 0.0035, with a warning)")
    p.add_argument("--degree", type=int, default=2, choices=[2],
                   help="the velocity's degree (Taylor-Hood: the pressure's is one less)")
    p.add_argument("--solver", choices=["auto", "direct", "iterative"], default="auto",
                   help="the linear solve: MUMPS' LU, FGMRES with a block preconditioner (AMG), or auto (default: "
                   "direct up to 150 000 unknowns where it fits in memory)")
    p.add_argument("--memory-limit", type=float, metavar="GB",
                   help="refuse a mesh whose solve would need more memory than this (default: what is available)")
    p.set_defaults(run=volume_commands.permeability)

