"""The output folder of a run (DESIGN.md section 8), written completely or not at all.

DIR/corrected.tg3        corrected model, a plain CTextile TexGen opens
DIR/corrected.json       the same in our format;  DIR/initial.json: the model before
DIR/metrics.json         metrics before/after (interpenetration, thickness, crimp, yarn volume, vf),
                         dofs, iterations, time per stage, parameters, versions
DIR/fields/yarn_I.bp     mid-surface fields of yarn I (w, z0, t, z = z0 + w, gap_below, contact) for
                         ParaView (VTX)
DIR/surfaces_before.vtu/.stl, DIR/surfaces_after.vtu/.stl   yarn surfaces clipped to the cell
DIR/view_before.png, DIR/view_after.png, DIR/cross_sections.png   figures
A run whose check on the corrected model failed (verify.py) writes all of the above, with the
corrected model named rejected.tg3/.json, and DIR/FAILED (the reasons). A run whose contact
iteration did not converge writes DIR/FAILED (the reason) and DIR/log.json (iteration log,
settings) only, and removes results of an earlier run there.
"""

import json
import logging
import platform
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

import dolfinx
import dolfinx.io
from textile_fenicsx import __version__
from textile_fenicsx.config import save_model
from textile_fenicsx.files import staged_folder
from textile_fenicsx.tg3 import write_tg3

log = logging.getLogger(__name__)


RESULT_NAMES = ("corrected.tg3", "corrected.json", "rejected.tg3", "rejected.json", "initial.json", "metrics.json",
                "fields", "surfaces_before.vtu", "surfaces_before.stl", "surfaces_after.vtu", "surfaces_after.stl", "view_before.png",
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


def metrics_document(run) -> dict:
    """metrics.json: the run's numbers before and after, the verdict of the check, the settings."""
    m = run.metrics
    before, after = m["before"], m["after"] or {}
    summary = run.summary()
    pick = (lambda key: {"before": before[key], "after": after.get(key)})
    return {
        "verdict": m["verdict"],
        "interpenetration": {k: (None if v is None else {f: v["interpenetration"][f] for f in
                                                         ("volume", "max_depth", "at", "pairs")})
                             for k, v in (("before", before), ("after", m["after"]))},
        "thickness": pick("thickness"), "crimp": pick("crimp"), "yarn_volume": pick("yarn_volume"),
        "yarn_volume_change": m.get("yarn_volume_change"), "section_area_change": m.get("section_area_change"),
        "vf": pick("vf"),
        "dofs": summary["dofs"], "cells": summary["cells"], "iterations": summary["iterations"],
        "converged": summary["converged"], "reason": summary["reason"],
        "penetration_nodal_mm": summary["max_penetration_nodal"], "max_abs_w_mm": summary["max_abs_w"],
        "time_s": dict(run.times),
        "parameters": asdict(run.settings.plate), "solver": asdict(run.settings.solver),
        "mesh": asdict(run.settings.mesh), "correction": asdict(run.settings.correction),
        "ranks": run.comm.size, "versions": versions(), "units": "mm, mm^3",
    }


def write_run(run, out, figures: bool = True, fields: bool = True, surfaces: bool = True) -> Path:
    """Write the run's folder `out` (collective); returns its path. fields, surfaces, figures: False
    leaves those parts out (the models and metrics.json are always written). A run whose check
    failed keeps everything for inspection, its corrected model named rejected.tg3/.json, and a
    FAILED file with the reasons."""
    comm = run.comm
    t0 = time.perf_counter()
    metrics = metrics_document(run)
    passed = metrics["verdict"]["passed"]
    stem = "corrected" if passed else "rejected"
    corrected = run.corrected
    with staged_folder(out, comm, remove=FAILED_NAMES + RESULT_NAMES) as tmp:
        log.info("outputs: models")
        if comm.rank == 0:
            write_tg3(corrected, tmp / f"{stem}.tg3")
            save_model(corrected, tmp / f"{stem}.json")
            save_model(run.textile, tmp / "initial.json")
            if not passed:
                (tmp / "FAILED").write_text("\n".join(f["message"] for f in metrics["verdict"]["failures"]) + "\n")
        if fields:
            log.info("outputs: mid-surface fields")
            if comm.rank == 0:
                (tmp / "fields").mkdir()
            comm.barrier()
            sol = run.solution
            for y, w, gap, contact in zip(run.midsurfaces.yarns, sol.w, sol.gap, sol.contact):
                z = dolfinx.fem.Function(y.V, name="z")
                z.x.array[:] = y.z0.x.array + w.x.array
                with dolfinx.io.VTXWriter(y.mesh.comm, tmp / "fields" / f"yarn_{y.yarn}.bp",
                                          [w, y.z0, y.t, z, gap, contact], engine="BP4") as vtx:
                    vtx.write(0.0)
        if comm.rank == 0 and (surfaces or figures):
            from textile_fenicsx.surfaces import YarnSurfaces

            log.info("outputs: surfaces")
            built = {name: YarnSurfaces.build(t) for name, t in (("before", run.textile), ("after", corrected))}
            for name, surf in built.items():
                if surf.open_yarns:
                    log.warning("outputs: the clipped surfaces of yarns %s (%s) could not be closed; written open",
                                surf.open_yarns, name)
                if surfaces:
                    surf.write(tmp / f"surfaces_{name}.vtu")
                    surf.write(tmp / f"surfaces_{name}.stl")
            if figures:
                from textile_fenicsx.plotting import plot_cross_sections, plot_textile

                log.info("outputs: figures")
                plot_textile(run.textile, built["before"], tmp / "view_before.png", f"{run.textile.name}: before")
                plot_textile(corrected, built["after"], tmp / "view_after.png", f"{run.textile.name}: after")
                plot_cross_sections(run.textile, corrected, tmp / "cross_sections.png", cut_lines(run.textile))
        metrics["time_s"]["outputs"] = time.perf_counter() - t0
        metrics["time_s"]["total"] = metrics["time_s"].get("total", 0.0) + metrics["time_s"]["outputs"]
        if comm.rank == 0:
            (tmp / "metrics.json").write_text(json.dumps(metrics, indent=1))
    return Path(out)


def write_failed(run, out) -> Path:
    """A run whose contact iteration failed: `out` holds FAILED (the reason) and log.json (the
    iteration log and the settings), nothing that could be mistaken for a result (collective)."""
    sol, comm = run.solution, run.comm
    document = {"reason": sol.reason, "iterations": sol.iterations, "history": sol.history,
                "parameters": asdict(run.settings.plate), "solver": asdict(run.settings.solver),
                "mesh": asdict(run.settings.mesh), "ranks": comm.size, "versions": versions()}
    with staged_folder(out, comm, remove=RESULT_NAMES) as tmp:
        if comm.rank == 0:
            (tmp / "FAILED").write_text(sol.reason + "\n")
            (tmp / "log.json").write_text(json.dumps(document, indent=1))
    return Path(out)
