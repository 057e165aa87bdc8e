"""What a run is asked to do (`Settings`) and what it produced (`Run`: the corrected textile, the
solution, the times of the stages, its metrics measured on first use, and its output folder)."""

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mpi4py import MPI

from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.common.limits import check_length
from textile_fenicsx.correction.correct import CorrectionOptions
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.pipeline.compaction import CompactionCurve, CompactionTarget
from textile_fenicsx.plate.mesh.midsurface import MidSurfaces
from textile_fenicsx.plate.mesh.projected import MeshOptions
from textile_fenicsx.plate.solver import Mould, PlateParameters, Solution, SolverOptions

__all__ = ["Run", "Settings"]


@dataclass(frozen=True)
class Settings:
    """Everything a run was asked to do. mould: the thickness of the mould the fabric is solved in
    [mm] (its cavity centred on the model's mid-plane; it closes only on a fabric that comes out
    thicker), "auto" (the default) for the thickness the textile is woven to where it states one
    (3D weaves: `Textile.thickness`; no more than the model's own thickness as its plates' nodes
    see it, so that what lies between the nodes stays inside too), None for none. compaction: press
    the relaxed fabric further, its yarns flattening (compaction.py), or None (rigid yarns).
    remesh: how many times a run whose corrected yarns overlap, and that fails no other check, or
    whose contact iteration reached its cap, or whose factor lost the plates where the yarns flatten
    (UnresolvedError), is done again with its seed times FINER (0: never;
    `_coarse_mesh_failures`). Not weaves with binder legs: what overlaps
    there is the binders' sides in the input, which no mesh moves (docs/sweep.md), and TexGen's
    refined orthogonal weave did not finish meshing at 0.35 mm in 17 minutes."""

    mesh: MeshOptions = MeshOptions()
    plate: PlateParameters = PlateParameters()
    solver: SolverOptions = SolverOptions()
    correction: CorrectionOptions = CorrectionOptions()
    mould: float | str | None = "auto"
    compaction: CompactionTarget | None = None
    remesh: int = 2

    def __post_init__(self):
        if not (isinstance(self.remesh, int) and 0 <= self.remesh <= 3):
            raise TextileError(f"remesh must be a whole number of times from 0 to 3, got {self.remesh!r}")
        if self.mould is not None and self.mould != "auto":
            check_length("mould thickness", self.mould)
            if self.solver.method != "exact":
                raise TextileError("a mould needs the exact contact method (its platens are constraints)")
        if self.compaction is not None and self.solver.method != "exact":
            raise TextileError("compaction needs the exact contact method (its platens are constraints)")

    def mould_thickness(self, textile: Textile) -> float | None:
        """The cavity's thickness for this textile [mm], None for no mould (auto: none with the
        penalty method)."""
        if self.mould == "auto":
            return textile.thickness if self.solver.method == "exact" else None
        return None if self.mould is None else float(self.mould)  # a number (__post_init__ checked it)


@dataclass
class Run:
    """Everything one run produced, with the time each stage took [s]. `corrected` is None when the
    contact iteration did not converge (`solution.reason` says why)."""

    textile: Textile
    settings: Settings
    midsurfaces: MidSurfaces
    solution: Solution
    corrected: Textile | None
    times: dict = field(default_factory=dict)
    mould: Mould | None = None  # the mould's platens, where it closed on the fabric
    compaction: CompactionCurve | None = None  # the platens' pressure against thickness, where pressed
    flats: list | None = None  # per textile yarn its flattening (correct.Flat), where pressed
    volume_ratio: list | None = None  # per textile yarn its plate's volume after / before, where pressed
    legs: bool = False  # binder legs that are not plates (legs.py)
    remeshed: list = field(default_factory=list)  # the runs done before this one: seed, failures, time
    spreading: list | None = None  # per textile yarn its width over the model's, where pressed yarns spread
    # per point of the compaction curve its corrected model and the platens' Mould (None: open), where
    # asked (CompactionTarget.step_models)
    step_models: list[tuple[Textile, Mould | None]] | None = None
    _metrics: dict | None = field(default=None, repr=False)

    def __repr__(self) -> str:
        sol = self.solution
        state = f"converged in {sol.iterations} Newton steps" if sol.converged else f"not converged ({sol.reason})"
        dofs = sum(y.V.dofmap.index_map.size_global for y in self.midsurfaces.yarns)
        check = "check not measured yet" if self._metrics is None else \
            ("check passed" if self.verdict["passed"] else "check failed")
        return (f"<Run {self.textile.name!r}: {state}, {dofs} dofs, seed {self.settings.mesh.seed:g} mm, "
                f"{self.times.get('total', 0.0):.1f} s; {check}>")

    def summary_line(self) -> str:
        """One line for people: the check's verdict, interpenetration and thickness before -> after,
        the size and the time of the run (collective: measures the metrics if not yet done)."""
        m = self.metrics
        before, after = m["before"], m["after"] or {}
        check = "check passed" if m["verdict"]["passed"] else "check FAILED"
        volume = (f"interpenetration {before['interpenetration']['volume']:.3g} -> "
                  f"{after['interpenetration']['volume']:.3g} mm^3") if after else "no corrected model"
        thickness = f", thickness {before['thickness']:.3f} -> {after['thickness']:.3f} mm" if after else ""
        s = self.summary()
        again = "".join(f"; meshed again at {self.settings.mesh.seed:g} mm, the run at {r['seed']:g} mm "
                        f"{'reached the step cap' if 'reached its cap' in r['failures'][0] else 'overlapped'} "
                        f"({r['time_s']:.1f} s)" for r in self.remeshed[-1:])
        spread = (f"; yarns spread to {min(self.spreading):.3f}-{max(self.spreading):.3f} x their width"
                  if self.spreading else "")
        return (f"{self.textile.name}: {check}; {volume}{thickness}{spread}; {s['dofs']} dofs, {s['iterations']} "
                f"Newton steps, {self.times.get('total', 0.0):.1f} s{again}")

    @property
    def comm(self) -> MPI.Comm:
        return self.midsurfaces.V.mesh.comm

    @property
    def converged(self) -> bool:
        return self.solution.converged

    def summary(self) -> dict:
        """JSON-ready numbers of the run (collective)."""
        local = max([float(np.max(np.abs(w.x.array))) for w in self.solution.w if len(w.x.array)] or [0.0])
        sol = self.solution
        return {
            "dofs": int(sum(y.V.dofmap.index_map.size_global for y in self.midsurfaces.yarns)),
            "cells": int(self.midsurfaces.projected.stats["cells"]),
            "iterations": sol.iterations, "updates": sol.updates, "converged": sol.converged,
            "reason": sol.reason, "max_penetration_nodal": sol.max_penetration,
            "max_abs_w": self.comm.allreduce(local, op=MPI.MAX), "time_s": dict(self.times),
            "mould": None if self.mould is None else {"bottom": self.mould.bottom, "top": self.mould.top,
                                                      "thickness": self.mould.thickness},
        }

    @property
    def metrics(self) -> dict:
        """Metrics before and after and the verdict of the check on the corrected model
        (`verify.assess`; collective, measured once)."""
        if self._metrics is None:
            from textile_fenicsx.correction.verify import assess

            t = time.perf_counter()
            self._metrics = assess(self)
            self.times["metrics"] = time.perf_counter() - t
        return self._metrics

    @property
    def verdict(self) -> dict:
        return self.metrics["verdict"]

    def write(self, out, figures: bool = True, fields: bool = True, surfaces: bool = True, painter=None) -> Path:
        """The run's output folder (outputs.write_run; collective)."""
        from textile_fenicsx.pipeline.outputs import write_run

        return write_run(self, out, figures=figures, fields=fields, surfaces=surfaces, painter=painter)
