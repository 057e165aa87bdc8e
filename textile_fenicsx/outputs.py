"""The output folder of a run (DESIGN.md section 8), written completely or not at all.

DIR/corrected.tg3        corrected model, a plain CTextile TexGen opens
DIR/corrected.json       the same in our format;  DIR/initial.json: the model before
DIR/metrics.json         metrics before/after (interpenetration, thickness, crimp, yarn volume, vf),
                         dofs, iterations, time per stage, parameters, versions
DIR/fields/yarn_I.bp     mid-surface fields of yarn I (w, z0, t, z = z0 + w, gap_below, contact) for
                         ParaView (VTX)
DIR/surfaces_before.vtu/.stl, DIR/surfaces_after.vtu/.stl   yarn surfaces clipped to the cell
DIR/view_before.png, DIR/view_after.png, DIR/cross_sections.png   figures
A failed run (the contact iteration did not converge) writes DIR/FAILED (the reason) and
DIR/log.json (iteration log, settings) instead, and removes results of an earlier run there.
"""

import json
import platform
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

import dolfinx
import dolfinx.io
from textile_fenicsx import __version__
from textile_fenicsx.config import save_model
from textile_fenicsx.export import write_surfaces
from textile_fenicsx.files import staged_folder
from textile_fenicsx.metrics import measure
from textile_fenicsx.solver import gap_fields
from textile_fenicsx.tg3 import write_tg3


RESULT_NAMES = ("corrected.tg3", "corrected.json", "initial.json", "metrics.json", "fields", "surfaces_before.vtu",
                "surfaces_before.stl", "surfaces_after.vtu", "surfaces_after.stl", "view_before.png",
                "view_after.png", "cross_sections.png")
FAILED_NAMES = ("FAILED", "log.json")


def versions() -> dict:
    import petsc4py
    import ufl

    return {"textile_fenicsx": __version__, "dolfinx": dolfinx.__version__, "ufl": ufl.__version__,
            "petsc4py": petsc4py.__version__, "python": platform.python_version()}


def cut_lines(textile) -> list:
    """Cutting lines for the cross-section figure: along the first yarn's centre, between it and its
    neighbour, and along the most crimped yarn's centre when that is another yarn (a binder)."""
    from textile_fenicsx.metrics import crimp

    def along(i):
        y = textile.yarns[i]
        axis = y.period[:2] / np.linalg.norm(y.period[:2])
        centre = np.mean(y.nodes[:-1], axis=0)[:2]
        x0, x1, ya, yb = textile.cell.bounds
        if abs(axis[0]) >= abs(axis[1]):
            return (x0, centre[1]), (x1, centre[1])
        return (centre[0], ya), (centre[0], yb)

    y0 = textile.yarns[0]
    a, b = along(0)
    lines = [("along yarn 0", a, b)]
    if abs(y0.period[0]) >= abs(y0.period[1]):
        centre = a[1]
        others = sorted(float(np.mean(y.nodes[:-1, 1])) for y in textile.yarns[1:]
                        if abs(y.period[0]) >= abs(y.period[1]))
        above = [o for o in others if o > centre + 1e-9]
        gap = (centre + (above[0] if above else centre + textile.cell.ly)) / 2
        lines.append(("between yarns", (a[0], gap), (b[0], gap)))
    k = int(np.argmax(crimp(textile)))
    if k != 0:
        a, b = along(k)
        lines.append((f"along {textile.yarns[k].name}", a, b))
    return lines


def write_run(result, corrected, out, params, options, mesh_options, figures: bool = True,
              log=None, extra_times: dict | None = None, fields: bool = True, surfaces: bool = True) -> Path:
    """Write the run's folder `out` (collective); returns its path. fields, surfaces, figures: False
    leaves those parts out (the models and metrics.json are always written)."""
    comm = result.midsurfaces.V.mesh.comm
    say = log if (log is not None and comm.rank == 0) else (lambda *_: None)
    t0 = time.perf_counter()
    before, after = measure(result.textile, 200, comm), measure(corrected, 200, comm)
    t_metrics = time.perf_counter() - t0
    summary = result.summary()
    metrics = {
        "interpenetration": {k: {"volume": m["interpenetration"]["volume"], "max_depth": m["interpenetration"]["max_depth"],
                                 "pairs": m["interpenetration"]["pairs"]} for k, m in (("before", before), ("after", after))},
        "thickness": {"before": before["thickness"], "after": after["thickness"]},
        "crimp": {"before": before["crimp"], "after": after["crimp"]},
        "yarn_volume": {"before": before["yarn_volume"], "after": after["yarn_volume"]},
        "vf": {"before": before["vf"], "after": after["vf"]},
        "dofs": summary["dofs"], "cells": summary["cells"], "iterations": summary["iterations"],
        "augmented_updates": summary["updates"], "converged": summary["converged"],
        "penetration_nodal_mm": summary["max_penetration_nodal"], "max_abs_w_mm": summary["max_abs_w"],
        "time_s": {**(extra_times or {}), **summary["time_s"]},
        "parameters": asdict(params), "solver": {k: v for k, v in asdict(options).items()},
        "mesh": asdict(mesh_options), "ranks": comm.size, "versions": versions(),
        "units": "mm, mm^3",
    }
    with staged_folder(out, comm, remove=FAILED_NAMES) as tmp:
        say("outputs: models")
        if comm.rank == 0:
            write_tg3(corrected, tmp / "corrected.tg3")
            save_model(corrected, tmp / "corrected.json")
            save_model(result.textile, tmp / "initial.json")
        if fields:
            say("outputs: mid-surface fields")
            if comm.rank == 0:
                (tmp / "fields").mkdir()
            comm.barrier()
            gaps = gap_fields(result.problem) if result.problem is not None else [()] * len(result.solution.w)
            for y, w, extra in zip(result.midsurfaces.yarns, result.solution.w, gaps):
                z = dolfinx.fem.Function(y.V, name="z")
                z.x.array[:] = y.z0.x.array + w.x.array
                with dolfinx.io.VTXWriter(y.mesh.comm, tmp / "fields" / f"yarn_{y.yarn}.bp",
                                          [w, y.z0, y.t, z, *extra], engine="BP4") as vtx:
                    vtx.write(0.0)
        if comm.rank == 0:
            if surfaces:
                say("outputs: surfaces")
                for name, textile in (("before", result.textile), ("after", corrected)):
                    write_surfaces(textile, tmp / f"surfaces_{name}.vtu")
                    write_surfaces(textile, tmp / f"surfaces_{name}.stl")
            if figures:
                from textile_fenicsx.plotting import plot_cross_sections, plot_textile

                say("outputs: figures")
                plot_textile(result.textile, tmp / "view_before.png", f"{result.textile.name}: before")
                plot_textile(corrected, tmp / "view_after.png", f"{result.textile.name}: after")
                plot_cross_sections(result.textile, corrected, tmp / "cross_sections.png", cut_lines(result.textile))
        metrics["time_s"]["metrics"] = t_metrics  # part of outputs
        metrics["time_s"]["outputs"] = time.perf_counter() - t0
        metrics["time_s"]["total"] = metrics["time_s"].get("total", 0.0) + metrics["time_s"]["outputs"]
        if comm.rank == 0:
            (tmp / "metrics.json").write_text(json.dumps(metrics, indent=1))
    return Path(out)


def write_failed(out, solution, params, options, mesh_options, comm) -> Path:
    """A run whose contact iteration failed: `out` holds FAILED (the reason) and log.json (the
    iteration log and the settings), nothing that could be mistaken for a result (collective)."""
    log = {"reason": solution.reason, "iterations": solution.iterations, "updates": solution.updates,
           "history": solution.history, "parameters": asdict(params), "solver": asdict(options),
           "mesh": asdict(mesh_options), "ranks": comm.size, "versions": versions()}
    with staged_folder(out, comm, remove=RESULT_NAMES) as tmp:
        if comm.rank == 0:
            (tmp / "FAILED").write_text(solution.reason + "\n")
            (tmp / "log.json").write_text(json.dumps(log, indent=1))
    return Path(out)
