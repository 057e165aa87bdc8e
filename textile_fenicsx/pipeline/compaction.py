"""Compaction (DESIGN.md 5a): the relaxed fabric pressed between platens to a thickness or a fibre
volume fraction, its yarns flattening by their compaction law (solver/flattening.py).

From the relaxed solve, the platens close in `steps` equal steps to the target thickness; each
step is one solve of the yarns that flatten, started from the step before (its unknowns and
forces: the interior point's warm start). The platens' pressure (their force over the cell) is
recorded against the thickness and the fabric's fibre volume fraction: the compaction curve. A step
that cannot be taken (the target beyond the maximum packing) ends the compaction with the reason;
the curve up to it is kept. Every step but the last is solved until its yarns move less than
STEP_TOL and its forces balance; the last, to the solver's own tolerance, and then once more where
its gap field dips below 0 between the nodes, with margins that keep it >= 0 there (as the relaxed
solve's second solve).
"""

import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import numpy as np
from mpi4py import MPI

from textile_fenicsx.common.errors import TextileError, check_positive
from textile_fenicsx.common.memory import release_freed_memory
from textile_fenicsx.model.fibres import DEFAULT_YARN_VF
from textile_fenicsx.model.metrics import mean_section_area
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.plate.mesh.midsurface import MidSurfaces, plate_extent, widen_margins
from textile_fenicsx.plate.solver import (
    Compaction,
    ContactProblem,
    Mould,
    PlateParameters,
    Solution,
    SolverOptions,
    solve_problem,
)
from textile_fenicsx.plate.solver.flattening import thinnest_stack
from textile_fenicsx.plate.solver.newton import DUAL_RTOL
from textile_fenicsx.plate.solver.parameters import HEXAGONAL

__all__ = ["CompactionCurve", "CompactionTarget", "compact", "fibre_volume"]


log = logging.getLogger(__name__)

# The displacement tolerance [mm] (at least) of the steps before the last. Their unknowns only
# start the next step, and their pressures need their forces in balance (DUAL_RTOL), not their
# yarns settled to 1e-6 mm: a step settled to STEP_TOL whose forces are out of balance goes on to
# the solver's tolerance (SolverOptions.settle_tol). Measured on satin4 (seed 0.5) to Vf 0.55 in
# 4 steps: their Newton steps 14, 14, 15 -> 12, 13, 13, their pressures within 4e-7 of the settled
# ones. The last step is settled: the margins of its re-solve come from it, and solved to 1e-5
# first, the target's pressure depended on the path by 2e-7 (satin4 at seed 0.25, 1 or 4 steps;
# 9e-11 settled). At 1e-4 mm (as the relaxed first solve) the steps' forces were out of balance by
# 4e-6-4e-4 (DESIGN.md 5a)
STEP_TOL = 1e-5


@dataclass(frozen=True)
class CompactionTarget:
    """How far to press the fabric. modulus: the yarns' Van Wyk constant k E_f [N/mm^2 = MPa];
    thickness: the platens' final distance [mm], or vf: the fabric's fibre volume fraction at the
    end [-] (one of the two); phi_max: the maximum packing [-]; steps: the platens' steps [-];
    spreading: the width spreading exponent s [-] (spreading.py: a yarn pressed to r of its volume
    widens by r^(-s) into the room beside it; 0, the default, keeps the widths, 1 the sections' areas);
    step_models: keep the corrected model of every point of the curve (Run.step_models: the volume
    mesh and permeability of each, api.permeability_curve; each costs a correction, under a second
    on satin4 at seed 0.5)."""

    modulus: float
    thickness: float | None = None
    vf: float | None = None
    phi_max: float = HEXAGONAL
    steps: int = 4
    spreading: float = 0.0
    step_models: bool = False

    def __post_init__(self):
        check_positive("compaction modulus", self.modulus)
        if (self.thickness is None) == (self.vf is None):
            raise TextileError("compaction: give the mould's thickness or the fibre volume fraction, one of the two")
        if self.thickness is not None:
            check_positive("compaction thickness", self.thickness)
        if self.vf is not None and not 0 < self.vf < self.phi_max:
            raise TextileError(f"compaction: the fibre volume fraction must lie between 0 and the maximum packing "
                               f"{self.phi_max:.4g}, got {self.vf:g}")
        if not (isinstance(self.steps, int) and 1 <= self.steps <= 100):
            raise TextileError(f"compaction steps must be a whole number from 1 to 100, got {self.steps!r}")
        if not (isinstance(self.spreading, (int, float)) and 0 <= self.spreading <= 1):
            raise TextileError(f"compaction spreading exponent must lie between 0 and 1, got {self.spreading!r}")


@dataclass
class CompactionCurve:
    """The platens' pressure against the fabric's thickness: one point per step, the relaxed
    fabric first (pressure 0). thickness [mm], vf [-], pressure [N/mm^2 = MPa], the densest
    yarn's fibre fraction [-], Newton steps [-], imbalance: how far the forces are from
    equilibrium when the step settled (dual residual over the largest internal force [-]; above
    solver.newton.DUAL_RTOL its pressure is uncertain); reason: why it ended early (None: it
    reached the target)."""

    thickness: list = field(default_factory=list)
    vf: list = field(default_factory=list)
    pressure: list = field(default_factory=list)
    densest: list = field(default_factory=list)
    iterations: list = field(default_factory=list)
    imbalance: list = field(default_factory=list)
    target: float = 0.0
    fibre_volume: float = 0.0
    reason: str | None = None
    K_m2: list | None = None  # per point the cell's permeability tensor (3 x 3) [m^2], where it was computed

    def add(self, thickness: float, pressure: float, densest: float, iterations: int, area: float,
            imbalance: float = 0.0) -> None:
        self.thickness.append(thickness)
        self.imbalance.append(imbalance)
        self.vf.append(self.fibre_volume / (area * thickness))
        self.pressure.append(pressure)
        self.densest.append(densest)
        self.iterations.append(iterations)

    def as_dict(self) -> dict:
        """The curve's columns (K_m2 only where the permeability was computed)."""
        d = asdict(self)
        if d["K_m2"] is None:
            del d["K_m2"]
        return d


def yarn_fibre_areas(textile: Textile) -> list[float]:
    """Each yarn's fibre cross-section [mm^2]: its fibre data's, or DEFAULT_YARN_VF of its mean section."""
    return [(y.fibres.fibre_area() if y.fibres is not None else None)
            or DEFAULT_YARN_VF * mean_section_area(y, textile.resolution) for y in textile.yarns]


def fibre_volume(textile: Textile) -> float:
    """The fibres' volume in the cell [mm^3]: each yarn's fibre cross-section times its length."""
    return float(sum(a * y.length() for a, y in zip(yarn_fibre_areas(textile), textile.yarns)))


def _densest(ms: MidSurfaces, law: Compaction, dt: list) -> float:
    """The largest intra-yarn fibre fraction at a node, phi0 t0 / t [-]."""
    local = max([float(np.max(law.fraction(y.yarn) * y.t.x.array / (y.t.x.array + d.x.array)))
                 for y, d in zip(ms.yarns, dt) if len(d.x.array)] or [0.0])
    return ms.V.mesh.comm.allreduce(local, op=MPI.MAX)


def compact(ms: MidSurfaces, textile: Textile, relaxed: Solution, target: CompactionTarget,
            phi0: list[float], plate: PlateParameters, options: SolverOptions, loads: dict,
            on_point: Callable[[Solution, Mould | None], None] | None = None):
    """Press the relaxed fabric (its solution `relaxed`, rigid yarns) to the target. Returns the last
    solution that converged (its w and dt), its mould, and the curve (collective). on_point(solution,
    mould), where given, is called at each point of the curve as it is added: the relaxed fabric
    first (mould None), then each step that converged, with its platens (collective)."""
    law = Compaction(target.modulus, tuple(phi0), target.phi_max)
    area = textile.cell.area
    curve = CompactionCurve(fibre_volume=fibre_volume(textile))
    lo, hi = plate_extent(ms, relaxed.w)
    relaxed_thickness = hi - lo
    if target.thickness is not None:
        curve.target = target.thickness
    else:
        assert target.vf is not None  # CompactionTarget has one of the two
        curve.target = curve.fibre_volume / (area * target.vf)
    curve.add(relaxed_thickness, 0.0, max(phi0), 0, area)
    if on_point is not None:
        on_point(relaxed, None)
    least, (x, y) = thinnest_stack(ms, law)
    log.info("compaction: from %.4f mm (Vf %.3f) to %.4f mm (Vf %.3f) in %d steps; packed to %.4g the yarns at "
             "(%.3f, %.3f) mm are %.4f mm thick", relaxed_thickness, curve.vf[0], curve.target,
             curve.fibre_volume / (area * curve.target), target.steps, target.phi_max, x, y, least)
    if curve.target >= relaxed_thickness:
        curve.reason = (f"the target ({curve.target:.4g} mm) is not thinner than the relaxed fabric "
                        f"({relaxed_thickness:.4g} mm): nothing to press")
        return None, None, curve
    mid = (lo + hi) / 2
    loose = replace(options, displacement_tol=max(options.displacement_tol, STEP_TOL),
                    settle_tol=options.displacement_tol)
    start, solution, mould = relaxed, None, None
    problem = None  # one problem for every step: the platens move (ContactProblem.renew)
    try:
        for k in range(1, target.steps + 1):
            h = relaxed_thickness + (curve.target - relaxed_thickness) * k / target.steps
            if h < least:  # no solve can take it: the nodes' constraints cannot all hold
                curve.reason = (f"step {k} of {target.steps} ({h:.4g} mm, Vf {curve.fibre_volume / (area * h):.3f}) "
                                f"is beyond the maximum packing {target.phi_max:.4g} of the compaction law: packed to "
                                f"it, the yarns stacked at ({x:.3f}, {y:.3f}) mm are still {least:.4g} mm thick (give "
                                "a thicker mould or a lower fibre volume fraction"
                                + (", or let the yarns spread: --spreading S)" if target.spreading == 0 else ")"))
                log.warning("compaction: %s", curve.reason)
                break
            step_mould = Mould(mid - h / 2, mid + h / 2)
            settle = options if k == target.steps else loose  # (the last step's margins come from its settled solution)
            if problem is None:
                problem = ContactProblem(ms, plate, settle, loads=loads, mould=step_mould, compaction=law)
                x0: np.ndarray = relaxed.unknowns[0]  # type: ignore[index]  # (unknowns, forces): the exact method's
                # one surface of unknowns -> two
                start = replace(relaxed, unknowns=(problem.numbering.local_surfaces(x0), relaxed.unknowns[1]))  # type: ignore[index]
            else:
                problem.renew(settle, step_mould)
            step = solve_problem(problem, start=start, keep=True)
            if not step.converged:
                curve.reason = f"step {k} of {target.steps} ({h:.4g} mm): {step.reason}"
                log.warning("compaction: %s", curve.reason)
                break
            if k == target.steps:  # the last: where its gap field dips below 0 between nodes, once more
                dip = widen_margins(ms, step.w, step.dt)  # with margins that keep it >= 0 there too
                if dip > 0:
                    log.info("compaction: margins widened by up to %.1e mm where the gap dips between nodes; the "
                             "last step again", dip)
                    problem.renew(options)
                    again = solve_problem(problem, start=step, keep=True)
                    if not again.converged:
                        curve.reason = f"step {k} of {target.steps} ({h:.4g} mm), with widened margins: {again.reason}"
                        log.warning("compaction: %s", curve.reason)
                        break
                    again.iterations += step.iterations
                    step = again
            solution, mould, start = step, step_mould, step
            assert step.pressure is not None and step.dt is not None  # a closed mould, yarns that flatten
            imbalance = float(step.history[-1].get("imbalance", 0.0))
            curve.add(h, step.pressure, _densest(ms, law, step.dt), step.iterations, area, imbalance)
            log.info("compaction step %d: %.4f mm, Vf %.3f, pressure %.4g MPa, densest yarn %.3f, %d Newton steps",
                     k, h, curve.vf[-1], step.pressure, curve.densest[-1], step.iterations)
            if on_point is not None:
                on_point(step, step_mould)
            if imbalance > DUAL_RTOL:
                packed = curve.densest[-1] >= target.phi_max * (1 - 1e-3)
                log.warning("compaction step %d: the pressure %.4g MPa is uncertain: the forces settled out of "
                            "balance by %.1e of the largest%s", k, step.pressure, imbalance,
                            " (yarns packed to the maximum under another yarn leave them so)" if packed else "")
    finally:
        if problem is not None:
            problem.destroy()
            release_freed_memory()
    return solution, mould, curve


def plot_curve(curve: CompactionCurve, path, title: str) -> None:
    """compaction.png: the platens' pressure against the fabric's thickness and its fibre volume
    fraction, and where it was computed the cell's permeability against the fibre volume fraction
    (matplotlib; rank 0)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = 2 if curve.K_m2 is None else 3
    fig, axes = plt.subplots(1, panels, figsize=(5 * panels, 4), constrained_layout=True)
    left, right = axes[0], axes[1]
    for ax, x, label in ((left, curve.thickness, "fabric thickness [mm]"),
                         (right, curve.vf, "fibre volume fraction Vf [-]")):
        ax.plot(x, curve.pressure, "o-", color="tab:blue", label="platen pressure (this model)")
        ax.set_xlabel(label)
        ax.set_ylabel("pressure [MPa]")
        ax.grid(True, alpha=0.3)
    left.axvline(curve.target, color="tab:red", ls="--", label=f"target {curve.target:.3f} mm")
    left.invert_xaxis()  # pressing goes to the right
    left.legend(loc="upper left", fontsize=8)
    phi = right.twinx()  # a fraction, on an axis of its own
    phi.plot(curve.vf, curve.densest, "s--", color="tab:green", label="densest yarn node's fibre fraction")
    phi.set_ylabel("intra-yarn fibre fraction [-]", color="tab:green")
    lines = right.get_legend_handles_labels(), phi.get_legend_handles_labels()
    right.legend(lines[0][0] + lines[1][0], lines[0][1] + lines[1][1], loc="upper left", fontsize=8)
    if curve.K_m2 is not None:
        _plot_permeability(axes[2], curve)
    fig.suptitle(title + ("" if curve.reason is None else " (stopped short)"))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _plot_permeability(ax, curve: CompactionCurve) -> None:
    """The diagonal of the cell's permeability against the fibre volume fraction, on a log scale
    (the points where it was computed)."""
    known = [(v, np.diag(np.asarray(K, float))) for v, K in zip(curve.vf, curve.K_m2 or []) if K is not None]
    if known:
        vf = [v for v, _ in known]
        diagonal = np.array([d for _, d in known])
        for i, (label, marker) in enumerate((("Kxx", "o-"), ("Kyy", "s--"), ("Kzz", "^-"))):
            ax.plot(vf, diagonal[:, i], marker, label=label)
        ax.legend(loc="upper right", fontsize=8)
    ax.set_yscale("log")
    ax.set_xlabel("fibre volume fraction Vf [-]")
    ax.set_ylabel("cell permeability [m$^2$]")
    ax.grid(True, which="both", alpha=0.3)
