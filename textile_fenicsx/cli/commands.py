"""What each `textile-fenicsx` command does (cli.py runs them; arguments.py parses their options).

Each command takes the parsed arguments and returns the exit code; errors are raised
(errors.py) and turned into exit codes and messages by cli.main. Every command prints little on
stdout (a summary line, file names; JSON only where asked or where JSON is its answer) and its
progress on stderr through the library's logger.
"""

import errno
import json
import sys
import time
from contextlib import contextmanager, nullcontext
from dataclasses import replace
from pathlib import Path

from textile_fenicsx.cli import volume_commands
from textile_fenicsx.common import limits
from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.common.files import claim_output, staged_folder
from textile_fenicsx.model.metrics import with_yarn_vf
from textile_fenicsx.version import __version__

__all__ = ["build", "load_input", "mesh", "report", "solve", "versions"]


def versions(_args) -> int:
    import petsc4py
    import ufl

    import dolfinx

    print(f"textile_fenicsx {__version__}")
    print(f"dolfinx {dolfinx.__version__} (git {dolfinx.git_commit_hash[:10]})")
    print(f"ufl {ufl.__version__}")
    print(f"petsc4py {petsc4py.__version__}")
    return 0


def report(args) -> int:
    from mpi4py import MPI

    from textile_fenicsx.io.config import load_model
    from textile_fenicsx.model.metrics import measure

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


def build(args) -> int:
    from mpi4py import MPI

    from textile_fenicsx.io.config import save_model
    from textile_fenicsx.io.tg3_write import write_tg3
    from textile_fenicsx.model.weaves import build
    from textile_fenicsx.plot.plotting import plot_textile
    from textile_fenicsx.plot.surfaces import YarnSurfaces

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
    textile = _repeated(_stacked(textile, args), args)
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


def mesh(args) -> int:
    from mpi4py import MPI

    import dolfinx.io
    from textile_fenicsx.correction.legs import plate_model
    from textile_fenicsx.io.config import load_model
    from textile_fenicsx.plate.mesh.midsurface import mesh_statistics, mid_surfaces
    from textile_fenicsx.plate.mesh.projected import MeshOptions, projected_mesh
    from textile_fenicsx.plot.plotting import plot_projected_mesh

    comm = MPI.COMM_WORLD
    options = MeshOptions(args.seed, args.sliver, args.max_slope, args.allow_steep, args.memory_limit)
    _check_repeat(args)
    textile = _repeated(load_model(args.model), args, options, comm.size)
    written = ["mesh.xdmf", "mesh.h5", "mesh.json", "mesh.png"]
    claim = claim_output(args.out, inputs=[args.model], names=written, force=args.force, comm=comm)
    with claim if args.out else nullcontext():
        start = time.perf_counter()
        split = plate_model(textile, options.seed)  # the plates the solve meshes: legs cut out
        projected = projected_mesh(split.plate, options, comm)
        ms = mid_surfaces(projected)
        stats = mesh_statistics(ms)
        stats["legs_cut"] = sorted({textile.yarns[c.yarn].name for c in split.crowns if not c.whole})
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
    from textile_fenicsx.model.weaves import PATTERNS

    return text in PATTERNS or text == "orthogonal"


def load_input(text: str, options: dict | None = None):
    """A model from a file (.tg3, .toml, .json) or a named weave with its default sizes, or the
    builder's `options` (solve's --shear and --set)."""
    from textile_fenicsx.io.config import load_model
    from textile_fenicsx.model.weaves import build

    if _named_weave(text):
        try:
            return build(text, **(options or {}))
        except TypeError as e:
            raise TextileError(f"weave {text}: {e}") from None
    if options:
        raise TextileError(f"--shear and --set apply to a named weave; the model file {text} carries its own sizes "
                           "and lattice")
    return load_model(text)  # checked against the size bounds by the readers


def _weave_options(args) -> dict:
    """A named weave's builder options from solve's --set KEY=VALUE and --shear DEG."""
    options = {}
    for item in getattr(args, "set", None) or []:
        if "=" not in item:
            raise TextileError(f"--set expects KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        options[key.strip()] = _parse_value(value.strip())
    if getattr(args, "shear", None) is not None:
        if args.input == "orthogonal":
            raise TextileError("--shear applies to the 2D weaves (plain, twill, satin, crowfoot_satin), not orthogonal")
        options["shear"] = args.shear
    return options


def _compaction(args) -> dict:
    """The Settings' mould and compaction from --mould, --compaction, --vf (checked: exit 2)."""
    from textile_fenicsx.pipeline.compaction import CompactionTarget

    if args.compaction is None:
        if args.vf is not None:
            raise TextileError("--vf needs --compaction K (the yarns' compaction law) to press the fabric to a fibre "
                               "volume fraction")
        if args.spreading:
            raise TextileError("--spreading needs --compaction K: the yarns spread only where they are pressed")
        return {"mould": args.mould}
    thickness = args.mould if isinstance(args.mould, float) else None
    if thickness is None and args.vf is None:
        raise TextileError("--compaction needs a target: --mould T (a thickness in mm) or --vf V")
    if thickness is not None and args.vf is not None:
        raise TextileError("--compaction takes one target: --mould T or --vf V, not both")
    return {"mould": None, "compaction": CompactionTarget(args.compaction, thickness, args.vf, args.max_packing,
                                                          args.compaction_steps, args.spreading,
                                                          step_models=args.permeability)}


def solve(args) -> int:
    from mpi4py import MPI

    from textile_fenicsx.correction.correct import CorrectionOptions
    from textile_fenicsx.pipeline.outputs import FAILED_NAMES, RESULT_NAMES, write_failed
    from textile_fenicsx.pipeline.stages import Settings, run
    from textile_fenicsx.plate.mesh.projected import MeshOptions
    from textile_fenicsx.plate.solver import PlateParameters, SolverError, SolverOptions

    comm = MPI.COMM_WORLD
    settings = Settings(  # every option checked before any work
        mesh=MeshOptions(args.seed, args.sliver, args.max_slope, args.allow_steep, args.memory_limit),
        plate=PlateParameters(Db1=args.db1, Db2=args.db2, Db12=args.db12, sigma1=args.sigma1, Ec=args.ec, Et=args.et),
        solver=SolverOptions(method=args.method, max_iterations=args.max_iterations,
                             penetration_tol=args.penetration_tol, out_of_core=args.out_of_core,
                             min_gap=args.min_gap),
        correction=CorrectionOptions(), remesh=args.remesh, **_compaction(args))
    _check_repeat(args)
    volume = volume_commands.solve_options(args)  # the volume mesh after the solve, or None
    flow = volume_commands.flow_options(args, volume)  # its permeability, or None
    t = time.perf_counter()
    model = load_input(args.input, _weave_options(args))
    if volume is not None and model.cell.shift:  # refused before the solve, not after it
        from textile_fenicsx.volume.stage import refuse_sheared

        refuse_sheared(model)
    textile = _repeated(_stacked(with_yarn_vf(model, args.yarn_vf), args), args, settings.mesh,
                        comm.size, settings.solver.bytes_per_dof)
    if volume is not None and settings.compaction is not None:  # the pressed yarns are denser: their
        volume = replace(volume, yarn_vf=None)  # fibre data (--yarn-vf's fibres, kept) gives their fraction
    settings, volume = volume_commands.with_gap(settings, textile, volume, args.min_gap)
    model_time = time.perf_counter() - t
    inputs = [] if _named_weave(args.input) else [args.input]
    names = RESULT_NAMES + FAILED_NAMES + (volume_commands.FILES if volume else ()) + \
        (volume_commands.PERMEABILITY_FILES if flow else ())
    claim = claim_output(args.out, inputs=inputs, names=names, force=args.force, comm=comm)
    with claim if args.out else nullcontext(), _painter(args, comm, textile) as painter:
        result = run(textile, settings, comm, on_corrected=_hand_over(painter))
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
        verdict = result.verdict
        line, summary = result.summary_line(), result.summary()
        if comm.rank == 0:
            print(line)
            if args.out:
                print(f"written to {args.out}/ (metrics.json: every number; docs/usage.md, The output folder)")
            if args.json:
                print((out / "metrics.json").read_text() if args.out else json.dumps({**summary, "verdict": verdict},
                                                                                    indent=1))
        if verdict["passed"] and volume is not None:
            cell = volume_commands.mesh_corrected(result, volume, args.out)
            if flow is not None:
                volume_commands.permeability_corrected(result, cell, volume, flow, args.out)
    if not verdict["passed"]:
        kept = f"; the outputs are kept in {args.out}/ (rejected.tg3, FAILED)" if args.out else ""
        skipped = ("; no volume mesh" + (" nor permeability" if flow else "")) if volume is not None else ""
        messages = [f["message"] for f in verdict["failures"]]
        if args.method == "exact" and any(f["check"].startswith("overlap") for f in verdict["failures"]) and \
                not any("give it room" in m for m in messages):
            # the corrected sections are rebuilt from plates meshed at the seed: a mesh too coarse
            # for the weave's crimp leaves them overlapping (the sweep's jammed plain weaves: 0.036
            # mm at seed 0.5, none at 0.35, where their thickness has converged)
            seeds = [r["seed"] for r in result.remeshed] + [result.settings.mesh.seed]
            messages.append(f"the plates were meshed at {' and '.join(f'{v:g}' for v in seeds)} mm: try a finer "
                            "--seed")
        raise SolverError("the corrected model fails its check: " + "; ".join(messages) + kept + skipped)
    return 0


def _painter(args, comm, textile):
    """The process that draws the figures (figures.Painter), started now so that its imports and
    X server are ready, and the input's view drawn, when the solve is done; on one rank only (on
    more it would take a core from the solve: write_run starts one after it)."""
    if not args.out or args.no_figures or comm.size > 1:
        return nullcontext()
    from textile_fenicsx.pipeline.outputs import input_figures
    from textile_fenicsx.plot.figures import Painter
    from textile_fenicsx.plot.surfaces import EXPORT, YarnSurfaces

    painter = Painter()
    try:  # the surfaces for the view and the run's files (write_run takes them from the painter)
        painter.draw(input_figures(textile, YarnSurfaces.build(textile, resolution=EXPORT)))
    except BaseException:
        painter.close(now=True)
        raise
    return painter


def _hand_over(painter):
    """on_corrected for stages.run: a run's corrected model and its surfaces go to the painter
    (`_painter`) before its check is measured, so that its figures are drawn meanwhile (satin4 at
    seed 0.25 waited 0.7-0.9 s for them after its other files when they were asked for with those
    files, none now); None without a painter."""
    if painter is None:
        return None
    from textile_fenicsx.pipeline.outputs import corrected_figures
    from textile_fenicsx.plot.surfaces import EXPORT, YarnSurfaces

    def hand_over(result) -> None:
        surfaces = YarnSurfaces.build(result.corrected, resolution=EXPORT)  # also the run's files'
        painter.draw(corrected_figures(result, surfaces), model=result.corrected)

    return hand_over


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


def _stacked(textile, args):
    """The model, or --plies N of it stacked with their offsets (given, or random with --ply-seed)."""
    from textile_fenicsx.model.plies import random_offsets, stack

    if args.plies == 1 and args.ply_offsets is None:
        return textile
    offsets = random_offsets(textile, args.plies, args.ply_seed)
    if args.ply_offsets is not None:
        try:
            offsets = [tuple(float(v) for v in text.split(",")) for text in args.ply_offsets]  # type: ignore[misc]
        except ValueError:
            given = " ".join(args.ply_offsets)
            raise TextileError(f"--ply-offsets: expected DX,DY pairs in mm, got {given!r}") from None
    return stack(textile, args.plies, offsets)


def _repeated(textile, args, mesh=None, ranks: int = 1, bytes_per_dof: float | None = None):
    """The model, or its nx x ny coupon when --repeat was given (with free edges if asked). With
    mesh options, the coupon's memory is estimated from the unit cell first (quick for any
    coupon), and a coupon too large for the memory is refused before it is built."""
    _check_repeat(args)
    if getattr(args, "repeat", None) is None:
        return textile
    from textile_fenicsx.model.coupon import tile

    if mesh is not None:
        from textile_fenicsx.common.memory import BYTES_PER_DOF
        from textile_fenicsx.plate.mesh.projected import check_memory

        check_memory(textile, mesh, ranks, tuple(args.repeat), bytes_per_dof or BYTES_PER_DOF)
    nx, ny = args.repeat
    return tile(textile, nx, ny, free_edges=args.free_edges)


def _named(path, write, *args):
    """write(*args), its errors naming `path`."""
    from textile_fenicsx.common.files import naming

    with naming(path):
        return write(*args)


@contextmanager
def _naming(path):
    """A native writer's failure (HDF5, ADIOS2 raise RuntimeError) as an OSError naming `path`."""
    from textile_fenicsx.common.files import naming

    with naming(path):
        try:
            yield
        except RuntimeError as e:
            raise OSError(errno.EIO, f"the writer failed ({e})", str(path)) from e
