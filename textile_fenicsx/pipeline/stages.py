"""One way through the house (DESIGN.md 2): textile -> projected mesh -> mid-surfaces -> solve ->
corrected textile. `run` does it and returns a `Run`: the corrected textile, the solution, the times
of the stages; its metrics (and the verdict of the check on the corrected model) are measured on
first use (in `run` itself where it may mesh again, Settings.remesh), and `write` makes the output
folder."""

import logging
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from mpi4py import MPI

import dolfinx
from textile_fenicsx.common.errors import MeshError, SolverError, TextileError, UnresolvedError
from textile_fenicsx.common.memory import release_freed_memory
from textile_fenicsx.correction.bend_fit import open_bends
from textile_fenicsx.correction.correct import Flat, corrected_textile
from textile_fenicsx.correction.leg_fit import fit_legs
from textile_fenicsx.correction.legs import leg_loads, plate_model
from textile_fenicsx.correction.slopes import slope_thickness
from textile_fenicsx.model.fibres import Fibres
from textile_fenicsx.model.metrics import yarn_fibre_fractions
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.pipeline.compaction import compact, yarn_fibre_areas
from textile_fenicsx.pipeline.runs import Run, Settings
from textile_fenicsx.pipeline.spreading import spread
from textile_fenicsx.plate.mesh.midsurface import (
    MidSurfaces,
    mid_surfaces,
    model_margins,
    plate_extent,
    widen_margins,
)
from textile_fenicsx.plate.mesh.projected import projected_mesh
from textile_fenicsx.plate.solver import (
    ContactProblem,
    Mould,
    Solution,
    SolverOptions,
    solve_problem,
)
from textile_fenicsx.plate.solver.flattening import fit_margins, law_thickness, rigid_stack

__all__ = ["Run", "Settings", "run"]  # Settings and Run live in runs.py

log = logging.getLogger(__name__)

# The first solve's displacement tolerance [mm] (at least; the second solve's is the solver's own).
# It only gives the slopes that thicken the plates and the second solve's start, and a start that
# is not yet pressed against the constraints suits an interior point: with 1e-4 instead of 1e-6
# satin4 at seed 0.25 took 23 steps over both solves instead of 34 (twill 18 vs 21, plain 16 vs 18,
# the orthogonal weave 27 vs 29), and the answers moved by at most 7.5e-7 mm, less than the
# tolerance of the second solve (at the precision floor newton.py's `floor` rule may stop it after
# a full step of 10 times this)
FIRST_SOLVE_TOL = 1e-4

# A run whose corrected yarns overlap, and fail nothing else, is done again on a mesh this much
# finer (Settings.remesh). The corrected sections are rebuilt from plates meshed at the seed, and a
# mesh too coarse for a weave's crimp leaves them overlapping between its nodes: the sweep's jammed
# plain weaves overlap 0.033-0.036 mm at seed 0.5 and not at 0.35, where their thickness has
# converged (docs/sweep.md); pressed to Vf 0.5, three of the four fabrics that overlap at 0.5 pass
# at 0.35. A contact iteration that wandered to its cap is done again too (_coarse_mesh_failures).
# Twice by default (Settings.remesh): pressed to Vf 0.5, the jammed plain weaves overlap 0.010 mm
# deep at 0.35, where a yarn is packed to the maximum, and pass at 0.245 (docs/sweep.md)
FINER = 0.7

# The automatic mould (--mould auto: the thickness a 3D weave is woven to) opens where the yarns
# stacked in it are thicker than it, by AUTO_MOULD_OPENING times the penetration its solve could not
# remove (the interior point stalls short of the true excess: the refined orthogonal weave at 1.7 mm
# stalled at 0.54 um, opened by 1.1 um at 0.34 um and converges at 1.705 mm), at most
# AUTO_MOULD_OPENINGS times, by at most AUTO_MOULD_SLACK of its thickness each (_opened_mould); a
# mould the user gives never opens
AUTO_MOULD_OPENING = 10.0
AUTO_MOULD_OPENINGS = 2
AUTO_MOULD_SLACK = 2e-2
# Where the yarns stacked at a node with their contact margins need more of the automatic mould
# than its openings reach, ROOM_FOR_STACK of it (flattening.rigid_stack; TexGen's orthogonal weave
# refined to 1.6 mm: 1.6888 mm), or where those openings fell short, room is made at once
# (_room_for_stack): the margins cut node by node to fit the mould less AUTO_MOULD_ROOM (the
# interior point's room inside its constraints), and where the plates alone do not fit, the mould
# opened to them and AUTO_MOULD_ROOM more, with a warning; the yarns do not flatten
ROOM_FOR_STACK = (1.0 + AUTO_MOULD_SLACK) ** AUTO_MOULD_OPENINGS
AUTO_MOULD_ROOM = 5e-3

# A weave with binder legs whose corrected yarns overlap is solved again this many times at most,
# with the overlap added to the contact margins where it lies (_settled)
SETTLE_ROUNDS = 3


def run(textile: Textile, settings: Settings = Settings(), comm: MPI.Comm = MPI.COMM_WORLD,
        on_stage: Callable[[str], None] | None = None, on_corrected: Callable[[Run], None] | None = None) -> Run:
    """Mesh the textile's projected regions, sample its mid-surfaces, solve for the displacements
    and correct the textile (collective over comm). on_stage(name) is called as each stage begins
    (mesh, midsurfaces, assemble, solve, correct), on every rank (the bench measures them so).
    on_corrected(run) is called with each run that has a corrected model as it becomes the one
    kept, before its check is measured (the CLI hands the corrected model's figures to its
    painter then, to be drawn while the check runs).
    Where the corrected yarns overlap, or the contact iteration wandered to its cap, or its
    factor lost the plates where the yarns flatten (UnresolvedError), the run is done again on a
    finer mesh (Settings.remesh; the check is then measured here); the Run returned is the last
    that converged, with the earlier ones in `remeshed`. Where pressed yarns spread
    (CompactionTarget.spreading), the widened fabric is solved again, in rounds until the widths
    settle (spreading.py); the Run returned is the last round's, its textile the widened model."""
    result = _remeshed(textile, settings, comm, on_stage, on_corrected)
    if settings.compaction is None or settings.compaction.spreading == 0:
        return result
    return spread(result, textile, settings.compaction,
                  lambda model: _remeshed(model, settings, comm, on_stage, on_corrected))


def _remeshed(textile: Textile, settings: Settings, comm: MPI.Comm, on_stage: Callable[[str], None] | None,
              on_corrected: Callable[[Run], None] | None = None) -> Run:
    """One run, meshed again finer while a coarse mesh may be why it fails (`run`)."""
    result: Run | None = None
    earlier: list[dict] = []  # the runs before the one kept
    why: list[str] = []
    spent = 0.0
    for attempt in range(settings.remesh + 1):
        if attempt:
            earlier.append({"seed": settings.mesh.seed, "failures": why, "time_s": spent})
            finer = replace(settings, mesh=replace(settings.mesh, seed=settings.mesh.seed * FINER))
            log.warning("remesh: at seed %g mm %s; meshing at %g mm and solving again (remesh=0: never)",
                        settings.mesh.seed, "; ".join(why), finer.mesh.seed)
            settings = finer
        start = time.perf_counter()
        try:
            again = _run(textile, settings, comm, on_stage)
        except (TextileError, SolverError, MeshError) as e:  # a finer mesh that cannot be made or held
            if result is None and isinstance(e, UnresolvedError) and attempt < settings.remesh:
                # the factor lost the plates, at a corner the mesh is too coarse for: mesh finer
                why, spent = [str(e)], time.perf_counter() - start
                continue
            if result is None:
                raise
            log.warning("remesh: at seed %g mm the run failed (%s); the run at %g mm is kept", settings.mesh.seed, e,
                        result.settings.mesh.seed)
            break
        if result is not None and not again.converged:
            log.warning("remesh: at seed %g mm the contact iteration did not converge either (%s); the run at %g mm "
                        "is kept", settings.mesh.seed, again.solution.reason, result.settings.mesh.seed)
            break
        again.remeshed, result = list(earlier), again
        if on_corrected is not None and again.corrected is not None:
            on_corrected(again)
        if attempt == settings.remesh:  # no finer run left (remesh=0: the check stays lazy)
            break
        why, spent = _coarse_mesh_failures(result), result.times["total"]
        if not why:
            break
    assert result is not None  # the first run returned, or its error was raised
    return result


def _coarse_mesh_failures(result: Run) -> list[str]:
    """What a finer mesh may mend (Settings.remesh), or []: the check's failures where every one
    is an overlap of the corrected yarns, or a contact iteration that reached its cap (our jammed
    plain weave wanders at 0.5 mm where four footprints nearly meet, by 1e-5 mm a step for 400
    steps, and converges at 0.35 in 25). Not a run that stopped for another reason
    (yarns that no position separates, a singular or non-convex system, unless the weights had
    outgrown the factor: UnresolvedError, which `run` catches), with binder legs, or by
    the penalty method, whose overlap is its own (collective: measures the check)."""
    if result.legs or result.settings.solver.method != "exact":
        return []
    if result.corrected is None:
        reason = result.solution.reason
        return [reason] if "reached its cap" in reason else []
    failures = result.verdict["failures"]
    if not failures or not all(f["check"].startswith("overlap") for f in failures):
        return []
    return [f["message"] for f in failures]


def _run(textile: Textile, settings: Settings, comm: MPI.Comm, on_stage: Callable[[str], None] | None) -> Run:
    """One run at settings' seed (`run`)."""
    times, mould = {}, None
    begin = on_stage or (lambda name: None)
    begin("mesh")
    start = t = time.perf_counter()
    split = plate_model(textile, settings.mesh.seed)  # binder legs are not plates (legs.py)
    if settings.compaction is not None and split.any:
        raise TextileError(f"{textile.name}: compaction of a weave with binder legs through the thickness is not "
                           "modelled (its legs are not plates and cannot flatten); press 2D weaves, or solve it "
                           "without compaction")
    projected = projected_mesh(split.plate, settings.mesh, comm, settings.solver.bytes_per_dof)
    times["mesh"] = time.perf_counter() - t
    begin("midsurfaces")
    t = time.perf_counter()
    ms = mid_surfaces(projected)
    release_freed_memory()
    times["midsurfaces"] = time.perf_counter() - t
    begin("assemble")
    t = time.perf_counter()
    loads = leg_loads(split, ms, settings.plate.sigma1, settings.mesh.seed)
    first_options = replace(settings.solver, displacement_tol=max(settings.solver.displacement_tol, FIRST_SOLVE_TOL))
    problem = ContactProblem(ms, settings.plate, first_options, loads=loads)
    release_freed_memory()
    times["assemble"] = time.perf_counter() - t
    begin("solve")
    t = time.perf_counter()
    try:
        solution = solve_problem(problem, keep=True)
        if solution.converged:  # once more with the thickness the new slopes give (slopes.py), and
            # margins that keep the gap field >= 0 between the nodes as well
            dip = widen_margins(ms, solution.w)
            change = slope_thickness(ms, solution.w)
            log.info("slopes: thickness changed by up to %.2f %%; margins widened by up to %.1e mm where the gap "
                     "dips between nodes; solving again", 100 * change, dip)
            first = solution
            auto = settings.mould == "auto"  # its mould may open: the problem is kept to move its platens
            mould = _closing_mould(ms, solution.w, settings.mould_thickness(textile), auto)
            if auto and mould is not None:  # yarns stacked thicker than the woven thickness: room made for them
                mould = _room_for_stack(mould, ms, settings.solver)
            woven = mould
            if mould is None:  # the same plates, pairs and pattern: only the gaps moved
                problem.renew(settings.solver)
            else:
                problem.destroy()
                problem = ContactProblem(ms, settings.plate, settings.solver, loads=loads, mould=mould)
            solution = solve_problem(problem, start=first, keep=auto)
            for _ in range(AUTO_MOULD_OPENINGS if auto else 0):
                opened = _opened_mould(mould, solution, settings.solver)
                if opened is None:
                    break
                mould, stalled = opened, solution
                problem.renew(settings.solver, mould)  # the platens move, as in a compaction's steps
                solution = solve_problem(problem, start=first, keep=True)
                solution.iterations += stalled.iterations  # every Newton step is counted
                solution.history = stalled.history + solution.history
            if auto and woven is not None and not solution.converged and "inside the mould" in solution.reason:
                roomy = _room_for_stack(woven, ms, settings.solver, reach=1.0)  # the openings fell short
                if roomy is not woven:
                    mould, stalled = roomy, solution
                    problem.renew(settings.solver, mould)
                    solution = solve_problem(problem, start=first, keep=True)
                    solution.iterations += stalled.iterations
                    solution.history = stalled.history + solution.history
            solution.iterations += first.iterations
            solution.history = first.history + solution.history
    finally:  # (destroying twice is harmless: the second solve has freed it already)
        problem.destroy()
        del problem
        release_freed_memory()
    times["solve"] = time.perf_counter() - t
    curve, flats, ratio = None, None, None
    models: list[tuple[Textile, Mould | None]] | None = None
    if solution.converged and settings.compaction is not None:
        begin("compact")
        t = time.perf_counter()
        phi0 = yarn_fibre_fractions(textile)[0]  # each yarn's relaxed fibre fraction
        models = [] if settings.compaction.step_models else None

        def keep(step: Solution, step_mould: Mould | None) -> None:  # a point's corrected model, as the curve grows
            assert models is not None
            step_flats = None if step.dt is None else _flats(ms, step, textile)
            models.append((_corrected(textile, split, step, settings, step_flats, fibres=True), step_mould))

        pressed, pressed_mould, curve = compact(ms, textile, solution, settings.compaction, phi0, settings.plate,
                                                settings.solver, loads, None if models is None else keep)
        if pressed is not None:
            solution, mould = pressed, pressed_mould
            flats, ratio = _flats(ms, solution, textile), _volume_ratio(ms, solution)
        times["compact"] = time.perf_counter() - t
    corrected = None
    if solution.converged:
        begin("correct")
        t = time.perf_counter()
        if models and flats is not None:  # the last point's model is the pressed fabric's
            corrected = models[-1][0]
        else:
            corrected = _corrected(textile, split, solution, settings, flats)
        times["correct"] = time.perf_counter() - t
    else:
        log.warning("solve: the contact iteration did not converge: %s", solution.reason)
    times["total"] = time.perf_counter() - start
    result = Run(textile, settings, ms, solution, corrected, times, mould=mould if solution.converged else None,
                 compaction=curve, flats=flats, volume_ratio=ratio, legs=split.any, step_models=models)
    if split.any and corrected is not None and settings.compaction is None:
        result = _settled(result, split, loads, begin)
    s = result.summary()
    log.info("solve: %d dofs, %d Newton steps, max penetration %.3e mm, max |w| %.4f mm, %s", s["dofs"],
             s["iterations"], s["max_penetration_nodal"], s["max_abs_w"],
             ", ".join(f"{k} {v:.2f} s" for k, v in times.items()))
    return result


def _corrected(textile: Textile, split, solution: Solution, settings: Settings, flats,
               fibres: bool = False) -> Textile:
    """The corrected model of a converged solve (correct.py), its binders' legs fitted into their
    gaps and their bends opened (leg_fit.py, bend_fit.py). Where pressed (flats), or asked (fibres:
    the relaxed point of a compaction curve), its yarns carry the fibres the compaction counts."""
    corrected = corrected_textile(split.textile, solution.w,  # (the model the plates were made from)
                                  settings.correction.station_spacing(settings.mesh.seed),
                                  settings.correction.section_points, split, flats)
    binders = split.binders
    if binders:  # legs reach sideways into their neighbours: fitted into the gaps (leg_fit.py)
        gap = settings.solver.min_gap  # the fits keep the gap the solve kept
        corrected = fit_legs(corrected, binders, settings.correction.section_points, gap)
        corrected = open_bends(corrected, binders, settings.correction.section_points, gap)
    if flats is not None or fibres:  # the fibres the compaction counted go with the flattened yarns
        corrected = replace(corrected, yarns=[replace(y, fibres=y.fibres or Fibres(area=a)) for y, a in
                                              zip(corrected.yarns, yarn_fibre_areas(textile))])
    return corrected


def _overlaps_only(result: Run) -> bool:
    """Does the run's check fail, and on the corrected yarns' overlap alone (collective)?"""
    failures = result.verdict["failures"]
    return bool(failures) and all(f["check"].startswith("overlap") for f in failures)


def _settled(result: Run, split, loads: dict, begin: Callable[[str], None]) -> Run:
    """A run with binder legs whose corrected yarns overlap, and that fails nothing else, solved
    again (SETTLE_ROUNDS at most) with the overlap the corrected model shows over each pair's
    cells added to the pair's margins there (midsurface.model_margins): such a weave is not meshed
    again finer (Settings.remesh). The run returned is the last whose solve converged."""
    settings, ms = result.settings, result.midsurfaces
    source = [c.yarn for c in split.crowns]
    for _ in range(SETTLE_ROUNDS if settings.solver.method == "exact" else 0):
        if not _overlaps_only(result):
            break
        begin("settle")
        t = time.perf_counter()
        added = model_margins(ms, result.solution.w, result.corrected, source)
        log.warning("settle: the corrected yarns overlap (%s); margins widened by up to %.1e mm where they do; "
                    "solving again", result.verdict["failures"][0]["message"].split(";")[0], added)
        problem = ContactProblem(ms, settings.plate, settings.solver, loads=loads, mould=result.mould)
        try:
            solution = solve_problem(problem, start=result.solution)
        finally:
            problem.destroy()
            del problem
            release_freed_memory()
        if not solution.converged:
            log.warning("settle: the contact iteration did not converge (%s); the run before is kept", solution.reason)
            break
        solution.iterations += result.solution.iterations
        solution.history = result.solution.history + solution.history
        times = dict(result.times)
        times["settle"] = times.get("settle", 0.0) + time.perf_counter() - t
        corrected = _corrected(result.textile, split, solution, settings, None)
        times["total"] = times["total"] + time.perf_counter() - t
        result = Run(result.textile, settings, ms, solution, corrected, times, mould=result.mould, legs=True)
    return result


def _closing_mould(ms: MidSurfaces, w: list, thickness: float | None, at_most_initial: bool) -> Mould | None:
    """A mould of the given thickness (at_most_initial: no thicker than the plates at the start)
    centred on the model's mid-plane, if the solved plates w are thicker than it (a mould that
    touches nothing holds nothing, and leaves the common translation free: the solve then keeps
    its pin); else None."""
    if thickness is None:
        return None
    lo0, hi0 = plate_extent(ms)
    if at_most_initial:
        thickness = min(thickness, hi0 - lo0)
    lo, hi = plate_extent(ms, w)
    if hi - lo <= thickness:
        log.info("mould: the fabric (%.4f mm) fits the mould's %.4f mm: it stays open", hi - lo, thickness)
        return None
    mid = (lo0 + hi0) / 2
    log.info("mould: the fabric came out %.4f mm thick, the mould is %.4f mm: solving again between its "
             "platens (z = %.4f, %.4f mm)", hi - lo, thickness, mid - thickness / 2, mid + thickness / 2)
    return Mould(mid - thickness / 2, mid + thickness / 2)


def _room_for_stack(mould: Mould, ms: MidSurfaces, options: SolverOptions, reach: float = ROOM_FOR_STACK) -> Mould:
    """The automatic mould, or where the yarns stacked at a node need more than `reach` of it
    (flattening.rigid_stack: their plates' thickness, the contact margins and the least gap; by
    default beyond what _opened_mould's openings reach), room made for them: the margins cut
    node by node where the stack with them is thicker than the mould less AUTO_MOULD_ROOM
    (flattening.fit_margins), and where the plates alone are thicker than that, the mould opened
    to them and AUTO_MOULD_ROOM more, about the same mid-plane; with a warning naming what was
    done and the thicknesses (a 3D weave's yarns do not flatten: DESIGN.md 5a). TexGen's
    orthogonal weave refined to 1.6 mm: its plates stack 1.5998 mm thick at most, but its sections
    touch over whole areas and its margins (up to 0.041 mm a pair at its warps' edges) sum to
    1.6888 mm down a stack (after the slopes)."""
    need, (x, y) = rigid_stack(ms, options.min_gap)
    if need <= reach * mould.thickness:
        log.info("mould: the yarns stacked at (%.3f, %.3f) mm need %.5f mm of its %.5f mm", x, y, need, mould.thickness)
        return mould
    bare = fit_margins(ms, np.inf, options.min_gap)[1]  # (nothing scaled)
    opened = max(mould.thickness, bare * (1 + AUTO_MOULD_ROOM))
    changed = fit_margins(ms, opened / (1 + AUTO_MOULD_ROOM), options.min_gap)[0]
    log.warning("mould: the yarns stacked at (%.3f, %.3f) mm need %.4f mm with their contact margins, %.1f %% more "
                "than the mould (%.4f mm, the thickness the model is woven to); their sections do not flatten in a "
                "3D weave: the margins are cut at %d nodes where the stack with them is thicker than the mould%s",
                x, y, need, 100 * (need / mould.thickness - 1), mould.thickness, changed,
                "" if opened == mould.thickness else
                f", and the plates alone stack {bare:.4f} mm: the mould is opened to {opened:.4f} mm")
    mid = (mould.bottom + mould.top) / 2
    return Mould(mid - opened / 2, mid + opened / 2)


def _opened_mould(mould: Mould | None, solution: Solution, options: SolverOptions) -> Mould | None:
    """The automatic mould (the thickness the model says it is woven to) opened, where the yarns
    stacked in it are thicker than it: by AUTO_MOULD_OPENING times the penetration its solve could
    not remove, if that is at most AUTO_MOULD_SLACK of its thickness; else None (the failure stands).
    TexGen's refine fits sections to its FabricThickness, but the plates' vertical thickness grows
    with their slope (slopes.py) and the exact contact keeps margins between nodes: the refined
    orthogonal weave at 1.7 mm stacks 0.54 um thicker than it."""
    if mould is None or solution.converged or not solution.history:
        return None
    penetration = float(solution.history[-1]["max_penetration"])
    opening = AUTO_MOULD_OPENING * penetration + 2 * options.penetration_tol
    if penetration <= options.penetration_tol or opening > AUTO_MOULD_SLACK * mould.thickness:
        return None
    log.warning("mould: the yarns stacked in the model's own thickness (%.4f mm) are %.2g mm thicker than it; "
                "the mould is opened by %.2g mm to %.5f mm and the fabric solved again", mould.thickness,
                penetration, opening, mould.thickness + opening)
    return Mould(mould.bottom - opening / 2, mould.top + opening / 2)


def _flats(ms: MidSurfaces, solution: Solution, textile: Textile) -> list:
    """Per yarn (a plate each) its flattening for the correction: dt / t and the range of its nodal values."""
    flats = []
    for y, dt in zip(ms.yarns, solution.dt or []):
        ratio = dolfinx.fem.Function(y.V, name="dt_over_t")
        # over the law's own relaxed thickness, not t (a yarn's edge nodes, t ~ 4e-6 mm, moved 1.6e-5 mm
        # apart by the spring and read 3.9)
        ratio.x.array[:] = dt.x.array / law_thickness(y)
        comm, r = y.mesh.comm, ratio.x.array
        bounds = (comm.allreduce(float(np.min(r, initial=0.0)), op=MPI.MIN),
                  comm.allreduce(float(np.max(r, initial=0.0)), op=MPI.MAX))
        flats.append(Flat(ratio, bounds, textile.cell))
    return flats


def _volume_ratio(ms: MidSurfaces, solution: Solution) -> list[float]:
    """Per yarn (a plate each) its volume after the compaction over before, int (t + dt) / int t [-]."""
    comm = ms.V.mesh.comm
    ratio = []
    for y, dt in zip(ms.yarns, solution.dt or []):
        before, after = (comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(f * y.dx)), op=MPI.SUM)
                         for f in (y.t, y.t + dt))
        ratio.append(after / before)
    return ratio
