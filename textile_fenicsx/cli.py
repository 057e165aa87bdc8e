"""The `textile-fenicsx` command line.

Exit codes (README, "When things go wrong"): 0 success; 1 the run failed (the contact iteration
did not converge, a singular or non-finite solve, a file that cannot be written, an internal
error); 2 bad input or usage (the message names the culprit); 130 interrupted (Ctrl-C, SIGTERM).
Under MPI an error on any rank prints its message and ends every rank (MPI_Abort), so no rank
waits forever in a collective call.
"""

import argparse
import errno
import json
import logging
import os
import signal
import sys
import time
import traceback
from contextlib import contextmanager, nullcontext
from pathlib import Path

from textile_fenicsx import __version__, limits
from textile_fenicsx.errors import OutputError, TextileError
from textile_fenicsx.files import claim_output, staged_folder


def _versions(_args) -> int:
    import dolfinx
    import petsc4py
    import ufl

    print(f"textile_fenicsx {__version__}")
    print(f"dolfinx {dolfinx.__version__} (git {dolfinx.git_commit_hash[:10]})")
    print(f"ufl {ufl.__version__}")
    print(f"petsc4py {petsc4py.__version__}")
    return 0


def _report(args) -> int:
    from mpi4py import MPI

    from textile_fenicsx.config import load_model
    from textile_fenicsx.metrics import measure

    limits.check_count("--grid", args.grid, 1, limits.MAX_GRID)
    textile = load_model(args.model)
    metrics = measure(textile, args.grid, comm=MPI.COMM_WORLD)
    if MPI.COMM_WORLD.rank == 0:
        print(json.dumps(metrics, indent=1))
    return 0


def _parse_value(text: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _build(args) -> int:
    from mpi4py import MPI

    from textile_fenicsx.config import save_model
    from textile_fenicsx.surfaces import YarnSurfaces
    from textile_fenicsx.plotting import plot_textile
    from textile_fenicsx.tg3 import write_tg3
    from textile_fenicsx.weaves import build

    options = {k: v for k, v in vars(args).items()
               if k in ("spacing", "width", "height", "thickness", "power", "over", "under", "harness", "move")
               and v is not None}
    if args.allow_overlap:
        options["allow_overlap"] = True
    for item in args.set or []:
        if "=" not in item:
            raise TextileError(f"--set expects KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        options[key.strip()] = _parse_value(value.strip())
    _check_repeat(args)
    try:
        textile = build(args.name, **options)
    except TypeError as e:
        raise TextileError(f"build {args.name}: {e}") from None
    textile.check_size()
    textile = _repeated(textile, args)
    if MPI.COMM_WORLD.rank != 0:
        return 0
    start = time.perf_counter()
    stem = args.name
    written = [f"{stem}.{ext}" for ext in ("json", "tg3", "vtu", "stl", "png")]
    with claim_output(args.out, names=written):
        surfaces = YarnSurfaces.build(textile)
        with staged_folder(args.out, remove=written) as tmp:
            steps = [("model", lambda: save_model(textile, tmp / f"{stem}.json")),
                     ("TexGen", lambda: write_tg3(textile, tmp / f"{stem}.tg3")),
                     ("surfaces", lambda: (surfaces.write(tmp / f"{stem}.vtu"), surfaces.write(tmp / f"{stem}.stl")))]
            if not args.no_picture:
                steps.append(("picture", lambda: _named(tmp / f"{stem}.png", plot_textile, textile, surfaces,
                                                        tmp / f"{stem}.png")))
            for label, step in steps:
                print(f"build: writing {label} ({time.perf_counter() - start:.1f} s)", file=sys.stderr, flush=True)
                step()
            names = sorted(f.name for f in tmp.iterdir())
    for name in names:
        print(Path(args.out) / name)
    return 0


def _mesh(args) -> int:
    from mpi4py import MPI

    import dolfinx.io
    from textile_fenicsx.config import load_model
    from textile_fenicsx.meshes.midsurface import mesh_statistics, mid_surfaces
    from textile_fenicsx.meshes.projected import MeshOptions, projected_mesh
    from textile_fenicsx.plotting import plot_projected_mesh

    comm = MPI.COMM_WORLD
    options = MeshOptions(args.seed, args.sliver, args.max_slope, args.allow_steep, args.memory_limit)
    _check_repeat(args)
    textile = _repeated(load_model(args.model), args, options, comm.size)
    written = ["mesh.xdmf", "mesh.h5", "mesh.json", "mesh.png"]
    claim = claim_output(args.out, inputs=[args.model], names=written, force=args.force, comm=comm)
    with claim if args.out else nullcontext():
        start = time.perf_counter()
        projected = projected_mesh(textile, options, comm)
        ms = mid_surfaces(projected)
        stats = mesh_statistics(ms)
        stats["time_s"] = time.perf_counter() - start
        if args.out:
            with staged_folder(args.out, comm, remove=written) as tmp:
                with _naming(tmp / "mesh.xdmf"):
                    with dolfinx.io.XDMFFile(comm, tmp / "mesh.xdmf", "w") as f:
                        f.write_mesh(projected.mesh)
                        projected.cell_tags.name = "covering_set"
                        f.write_meshtags(projected.cell_tags, projected.mesh.geometry)
                if comm.rank == 0:
                    _named(tmp / "mesh.json", (tmp / "mesh.json").write_text, json.dumps(stats, indent=1))
                if not args.no_picture:
                    _named(tmp / "mesh.png", plot_projected_mesh, projected, tmp / "mesh.png")
    if comm.rank == 0:
        print(json.dumps(stats, indent=1))
    return 0


def _named_weave(text: str) -> bool:
    from textile_fenicsx.weaves import PATTERNS

    return text in PATTERNS or text == "orthogonal"


def load_input(text: str):
    """A model from a file (.tg3, .toml, .json) or a named weave with its default sizes."""
    from textile_fenicsx.config import load_model
    from textile_fenicsx.weaves import build

    if _named_weave(text):
        return build(text)
    return load_model(text)  # checked against the size bounds by the readers


def _solve(args) -> int:
    from mpi4py import MPI

    from textile_fenicsx.correct import CorrectionOptions
    from textile_fenicsx.meshes.projected import MeshOptions
    from textile_fenicsx.outputs import FAILED_NAMES, RESULT_NAMES, write_failed
    from textile_fenicsx.pipeline import Settings, run
    from textile_fenicsx.solver import PlateParameters, SolverError, SolverOptions

    comm = MPI.COMM_WORLD
    settings = Settings(  # every option checked before any work
        mesh=MeshOptions(args.seed, args.sliver, args.max_slope, args.allow_steep, args.memory_limit),
        plate=PlateParameters(Db1=args.db1, Db2=args.db2, Db12=args.db12, sigma1=args.sigma1, Ec=args.ec, Et=args.et),
        solver=SolverOptions(method=args.method, max_iterations=args.max_iterations,
                             penetration_tol=args.penetration_tol, out_of_core=args.out_of_core,
                             min_gap=args.min_gap),
        correction=CorrectionOptions(), mould=args.mould)
    _check_repeat(args)
    t = time.perf_counter()
    textile = _repeated(load_input(args.input), args, settings.mesh, comm.size, settings.solver.bytes_per_dof)
    model_time = time.perf_counter() - t
    inputs = [] if _named_weave(args.input) else [args.input]
    claim = claim_output(args.out, inputs=inputs, names=RESULT_NAMES + FAILED_NAMES, force=args.force, comm=comm)
    with claim if args.out else nullcontext(), _painter(args, comm, textile) as painter:
        result = run(textile, settings, comm)
        result.times["model"] = model_time
        if not result.converged:
            where = ""
            if args.out:
                write_failed(result, args.out)
                where = f"; {args.out}/ holds only FAILED and log.json (the iteration log)"
            hint = " (try a larger --max-iterations)" if "cap" in result.solution.reason else ""
            raise SolverError(f"{result.solution.reason}{hint}{where}")
        if args.out:  # the check's metrics are measured while the figures are drawn
            out = result.write(args.out, figures=not args.no_figures, painter=painter)
            if comm.rank == 0:
                print((out / "metrics.json").read_text())
        verdict = result.verdict
        if not args.out and comm.rank == 0:
            print(json.dumps({**result.summary(), "verdict": verdict}, indent=1))
    if not verdict["passed"]:
        kept = f"; the outputs are kept in {args.out}/ (rejected.tg3, FAILED)" if args.out else ""
        raise SolverError("the corrected model fails its check: "
                          + "; ".join(f["message"] for f in verdict["failures"]) + kept)
    return 0


def _painter(args, comm, textile):
    """The process that draws the figures (figures.Painter), started now so that its imports and
    X server are ready, and the input's view drawn, when the solve is done; on one rank only (on
    more it would take a core from the solve: write_run starts one after it)."""
    if not args.out or args.no_figures or comm.size > 1:
        return nullcontext()
    from textile_fenicsx.figures import Painter
    from textile_fenicsx.outputs import input_figures

    painter = Painter()
    try:
        painter.draw(input_figures(textile))
    except BaseException:
        painter.close(now=True)
        raise
    return painter


def _check_repeat(args) -> None:
    """--repeat and --free-edges, checked before any model is read."""
    if getattr(args, "repeat", None) is None:
        if getattr(args, "free_edges", False):
            raise TextileError("--free-edges needs --repeat NX NY (use --repeat 1 1 for one cell)")
        return
    for label, n in zip(("nx", "ny"), args.repeat):
        if n < 1:
            raise TextileError(f"coupon repeats {label} must be a whole number >= 1, got {n!r}")
        limits.check_count(f"coupon repeats {label} (--repeat)", n, 1, limits.MAX_REPEATS)


def _repeated(textile, args, mesh=None, ranks: int = 1, bytes_per_dof: float | None = None):
    """The model, or its nx x ny coupon when --repeat was given (with free edges if asked). With
    mesh options, the coupon's memory is estimated from the unit cell first (quick for any
    coupon), and a coupon too large for the memory is refused before it is built."""
    _check_repeat(args)
    if getattr(args, "repeat", None) is None:
        return textile
    from textile_fenicsx.coupon import tile

    if mesh is not None:
        from textile_fenicsx.meshes.projected import BYTES_PER_DOF, check_memory

        check_memory(textile, mesh, ranks, tuple(args.repeat), bytes_per_dof or BYTES_PER_DOF)
    return tile(textile, *args.repeat, free_edges=args.free_edges)


def _named(path, write, *args):
    """write(*args), its errors naming `path`."""
    from textile_fenicsx.files import naming

    with naming(path):
        return write(*args)


@contextmanager
def _naming(path):
    """A native writer's failure (HDF5, ADIOS2 raise RuntimeError) as an OSError naming `path`."""
    from textile_fenicsx.files import naming

    with naming(path):
        try:
            yield
        except RuntimeError as e:
            raise OSError(errno.EIO, f"the writer failed ({e})", str(path)) from e


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
    commands = parser.add_subparsers(title="commands", metavar="COMMAND")

    p = commands.add_parser("versions", help="print the versions of the numerical stack")
    p.set_defaults(run=_versions)

    p = commands.add_parser(
        "report", help="print the metrics of a model as JSON",
        description="Measure a model (.tg3 from TexGen, or our .toml/.json) on an N x N grid of vertical "
        "rays: yarn volumes, interpenetration volume and depth (total and per yarn pair), thickness, "
        "crimp per yarn, fibre volume fraction (null without fibre data). mm and mm^3.")
    p.add_argument("model", help="model file: .tg3, .toml or .json")
    p.add_argument("--grid", type=int, default=200, metavar="N",
                   help="rays per cell side (default 200, as the reference measurements)")
    p.set_defaults(run=_report)

    p = commands.add_parser(
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
    _repeat_argument(p)
    p.add_argument("--no-picture", action="store_true", help="skip the PNG")
    p.set_defaults(run=_build)

    p = commands.add_parser(
        "mesh", help="mesh a model's projected regions and print mesh statistics as JSON",
        description="Mesh the unit cell by the sets of yarns covering it (gmsh; periodic sides; element "
        "size = seed) and sample each yarn's mid-surface. Prints JSON: cells, nodes, dofs per yarn, "
        "minimum angle, footprint area per yarn (mesh vs model), thickness integral vs yarn volume, "
        "contact pairs, time. With --out, writes DIR/mesh.xdmf (+.h5, cell tags = covering set), "
        "DIR/mesh.json and DIR/mesh.png. Runs under mpirun.")
    p.add_argument("model", help="model file: .tg3, .toml or .json")
    p.add_argument("--out", metavar="DIR", help="write mesh.xdmf, mesh.json and mesh.png there")
    p.add_argument("--force", action="store_true",
                   help="allow --out to be the model's own folder (the model file itself is never replaced)")
    _mesh_arguments(p)
    _repeat_argument(p)
    p.add_argument("--no-picture", action="store_true", help="skip the PNG")
    p.set_defaults(run=_mesh)

    p = commands.add_parser(
        "solve", help="correct a model: mesh, then minimise bending + tension + contact energy",
        description="Run the whole path on INPUT (a .tg3, our .toml/.json, or a named weave: plain, twill, "
        "satin, crowfoot_satin, orthogonal): projected mesh, mid-surfaces, then the contact iteration, "
        "printing one line per iteration (active contact dofs, changes, max penetration, residual, time). "
        "Prints a JSON summary (dofs, iterations, max penetration, max |w|, seconds per stage). With --out DIR "
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
    p.add_argument("--out", metavar="DIR", help="write the corrected model, metrics, fields, surfaces, figures")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
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
    p.add_argument("--min-gap", type=float, default=0.0, metavar="G",
                   help="exact method: keep yarns in contact (and a mould's platens) at least G mm apart, their "
                   "sections unchanged (0: they touch); a tet mesh (volume-mesh --kind tet) needs G > 0")
    p.add_argument("--out-of-core", action="store_true",
                   help="MUMPS keeps its factors on disk ($MUMPS_OOC_TMPDIR, else /tmp): less memory for large "
                   "coupons (README, Performance), somewhat slower")
    p.add_argument("--mould", type=_mould, default="auto", metavar="auto|none|T",
                   help="solve the fabric in a mould of thickness T [mm], its cavity centred on the model's "
                   "mid-plane, closing only on a fabric that comes out thicker (exact method); auto (default): "
                   "the thickness a 3D weave is woven to (TexGen's FabricThickness), none for other fabrics")
    p.set_defaults(run=_solve)
    return parser


def _mould(text: str):
    """--mould's value: "auto", None ("none") or a thickness [mm]."""
    if text in ("auto", "none"):
        return None if text == "none" else text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, none or a thickness in mm, got {text!r}") from None


EXIT_OK, EXIT_FAILED, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


def _interrupt(signum, _frame):
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _fail(code: int, message: str, collective: bool = False) -> int:
    """Report an error from this rank and, under MPI, end every rank with the exit code.
    collective: every rank raised the same error at the same place (files.claim_output): rank 0
    reports it and every rank returns the code."""
    rank, size = 0, 1
    if "mpi4py.MPI" in sys.modules:
        from mpi4py import MPI

        rank, size = MPI.COMM_WORLD.rank, MPI.COMM_WORLD.size
    if collective and size > 1:
        if rank == 0:
            print(f"textile-fenicsx: error: {message}", file=sys.stderr, flush=True)
        return code
    where = f" (rank {rank})" if size > 1 and rank else ""
    print(f"textile-fenicsx: error{where}: {message}", file=sys.stderr, flush=True)
    if size > 1:
        sys.stderr.flush()
        MPI.COMM_WORLD.Abort(code)
    return code


def _log_to_stderr() -> None:
    """Progress lines (the library's logging, INFO) to stderr, from rank 0 only."""
    rank = 0
    if "mpi4py.MPI" in sys.modules or "OMPI_COMM_WORLD_RANK" in os.environ:
        rank = int(os.environ.get("OMPI_COMM_WORLD_RANK", os.environ.get("PMI_RANK", "0")))
    root = logging.getLogger("textile_fenicsx")
    root.handlers.clear()
    if rank == 0:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(message)s"))
        root.addHandler(handler)
        root.setLevel(logging.INFO)
    else:
        root.addHandler(logging.NullHandler())
    root.propagate = False


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "run"):
        parser.print_help()
        return EXIT_INPUT
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)
    from textile_fenicsx.errors import SolverError

    _log_to_stderr()
    try:
        return args.run(args)
    except TextileError as e:
        return _fail(EXIT_INPUT, str(e), getattr(e, "collective", False))
    except (SolverError, OutputError) as e:
        return _fail(EXIT_FAILED, str(e), getattr(e, "collective", False))
    except KeyboardInterrupt as e:
        return _fail(EXIT_INTERRUPTED, f"interrupted ({str(e) or 'SIGINT'}); no output was written")
    except OSError as e:
        return _fail(EXIT_FAILED, f"cannot read or write {e.filename or 'a file'}: {e.strerror or e}",
                     getattr(e, "collective", False))
    except Exception as e:  # a bug: say so, with the traceback, and still end every rank
        traceback.print_exc()
        return _fail(EXIT_FAILED, f"internal error {type(e).__name__}: {e}")


if __name__ == "__main__":
    sys.exit(main())
