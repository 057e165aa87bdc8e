"""The output folder of a run (DESIGN.md section 8), written completely or not at all.

DIR/corrected.tg3        corrected model, a plain CTextile TexGen opens
DIR/corrected.json       the same in our format;  DIR/initial.json: the model before
DIR/metrics.json         metrics before/after (interpenetration, thickness, crimp, yarn volume, vf),
                         dofs, iterations, time per stage, parameters, versions
DIR/fields/yarn_I.vtu    mid-surface fields of yarn I over its cells in the unit cell, at the mesh's
                         vertices (points at x, y, z0 + w): w, z0, t, z = z0 + w, gap_below, contact;
                         cell data yarn (ParaView, meshio, pyvista)
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
from textile_fenicsx.common.files import atomic_path, naming, output_lock, staged_folder
from textile_fenicsx.io.config import save_model
from textile_fenicsx.io.tg3_write import write_tg3
from textile_fenicsx.version import __version__

log = logging.getLogger(__name__)


RESULT_NAMES = ("corrected.tg3", "corrected.json", "rejected.tg3", "rejected.json", "initial.json", "metrics.json",
                "fields", "surfaces_before.vtu", "surfaces_before.stl", "surfaces_after.vtu", "surfaces_after.stl",
                "view_before.png", "view_after.png", "cross_sections.png", "compaction.json", "compaction.png")
FAILED_NAMES = ("FAILED", "log.json")


def versions() -> dict:
    import petsc4py
    import ufl

    return {"textile_fenicsx": __version__, "dolfinx": dolfinx.__version__, "ufl": ufl.__version__,
            "petsc4py": petsc4py.__version__, "python": platform.python_version()}


def cut_lines(textile) -> list:
    """Cutting lines for the cross-section figure: along the first yarn's centre, between it and its
    neighbour, and along the most crimped yarn's centre when that is another yarn (a binder)."""
    from textile_fenicsx.model.metrics import crimp

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
    lines = [(f"along {y0.name}", a, b)]
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

    def pick(key):
        return {"before": before[key], "after": after.get(key)}

    return {
        "verdict": m["verdict"],
        "interpenetration": {k: (None if v is None else {f: v["interpenetration"][f] for f in
                                                         ("volume", "max_depth", "at", "pairs")})
                             for k, v in (("before", before), ("after", m["after"]))},
        "thickness": pick("thickness"), "crimp": pick("crimp"), "yarn_volume": pick("yarn_volume"),
        "yarn_volume_change": m.get("yarn_volume_change"),
        "yarn_volume_per_length_change": m.get("yarn_volume_per_length_change"),
        "section_area_change": m.get("section_area_change"),
        "yarn_surface_volume_per_length_change": m.get("yarn_surface_volume_per_length_change"),
        "yarn_folded_fraction": m.get("yarn_folded_fraction"),
        "vf": pick("vf"),
        "areal": pick("areal"),
        "shear_angle_deg": run.textile.cell.shear_angle,
        "plies": run.textile.plies,
        "thickness_per_ply": {k: (None if v is None else v / run.textile.plies)
                              for k, v in pick("thickness").items()},
        "dofs": summary["dofs"], "cells": summary["cells"], "iterations": summary["iterations"],
        "converged": summary["converged"], "reason": summary["reason"],
        "penetration_nodal_mm": summary["max_penetration_nodal"], "max_abs_w_mm": summary["max_abs_w"],
        "time_s": dict(run.times),
        "parameters": asdict(run.settings.plate), "solver": asdict(run.settings.solver),
        "mesh": asdict(run.settings.mesh), "correction": asdict(run.settings.correction),
        "remeshed": run.remeshed,
        "mould": {"asked": run.settings.mould, "closed": summary["mould"]},
        "compaction": None if run.compaction is None else {
            "target_mm": run.compaction.target, "thickness_mm": run.compaction.thickness[-1],
            "pressure_MPa": run.compaction.pressure[-1], "densest_yarn_vf": max(run.compaction.densest),
            "stopped": run.compaction.reason, "settings": asdict(run.settings.compaction),
            "width_factors": run.spreading},
        "ranks": run.comm.size, "versions": versions(), "units": "mm, mm^3",
    }


def input_figures(textile, surfaces=None) -> list[tuple[str, str, tuple]]:
    """The figures of a run that need only its input (the before view), as jobs for a
    figures.Painter: the CLI hands them over before the solve, to be drawn while it runs (with
    surfaces None the painter builds them)."""
    return [("textile", "view_before.png", (textile, surfaces, f"{textile.name}: before"))]


def corrected_figures(run, surfaces=None) -> list[tuple[str, str, tuple]]:
    """The figures of a run's corrected model (its view, the cross-sections before and after), as
    jobs for a figures.Painter: the CLI hands them over as soon as the run has its corrected model
    (stages.run's on_corrected), to be drawn while its check is measured (with surfaces None the
    painter builds them)."""
    corrected = run.corrected
    return [("textile", "view_after.png", (corrected, surfaces, f"{run.textile.name}: after")),
            ("cross_sections", "cross_sections.png", (run.textile, corrected, cut_lines(run.textile)))]


def write_run(run, out, figures: bool = True, fields: bool = True, surfaces: bool = True, painter=None) -> Path:
    """Write the run's folder `out` (collective); returns its path. fields, surfaces, figures: False
    leaves those parts out (the models and metrics.json are always written). The figures are drawn
    by a figures.Painter while the rest is written: `painter`, one started earlier (rank 0; the
    CLI starts it before the solve, so that its imports are done by then), else one of its own.
    A run whose check failed keeps everything for inspection, its corrected model named
    rejected.tg3/.json, and a FAILED file with the reasons."""
    comm = run.comm
    with output_lock(out, comm):  # first: a folder that cannot be written fails before the metrics
        if not figures or comm.rank != 0 or painter is not None:
            return _write_run(run, out, figures, fields, surfaces, painter)
        from textile_fenicsx.plot.figures import Painter

        with Painter() as own:
            return _write_run(run, out, figures, fields, surfaces, own)


def _write_run(run, out, figures: bool, fields: bool, surfaces: bool, painter) -> Path:
    comm = run.comm
    t0 = time.perf_counter()
    corrected = run.corrected
    with staged_folder(out, comm, remove=FAILED_NAMES + RESULT_NAMES) as tmp:
        built = {}
        if comm.rank == 0 and (surfaces or figures):
            from textile_fenicsx.plot.surfaces import EXPORT, YarnSurfaces

            log.info("outputs: surfaces")
            given = painter.surfaces if painter is not None else {}  # those the figures were given
            for name, t in (("before", run.textile), ("after", corrected)):
                model, surf = given.get(id(t), (None, None))
                built[name] = surf if model is t else YarnSurfaces.build(t, resolution=EXPORT)
            if figures:  # drawn while the other files are written (those asked for earlier, while the
                # check was measured: the corrected model's, unless the painter last drew another's)
                log.info("outputs: figures (drawn in the background)")
                painter.draw([f for f in input_figures(run.textile, built["before"]) if f[1] not in painter.asked])
                painter.draw([f for f in corrected_figures(run, built["after"])
                              if painter.models.get(f[1]) is not corrected], model=corrected)
        t1 = time.perf_counter()
        metrics = metrics_document(run)  # measures them, unless they were already
        t0 += time.perf_counter() - t1
        passed = metrics["verdict"]["passed"]
        stem = "corrected" if passed else "rejected"
        log.info("outputs: models")
        if comm.rank == 0:
            write_tg3(corrected, tmp / f"{stem}.tg3")
            save_model(corrected, tmp / f"{stem}.json")
            save_model(run.textile, tmp / "initial.json")
            if not passed:
                _write_text(tmp / "FAILED", "\n".join(f["message"] for f in metrics["verdict"]["failures"]) + "\n")
            if run.compaction is not None:
                write_compaction(run, tmp)
        if fields:
            log.info("outputs: mid-surface fields")
            write_fields(run, tmp / "fields")
        for name, surf in built.items():
            if surf.open_yarns:
                log.warning("outputs: the clipped surfaces of yarns %s (%s) could not be closed; written open",
                            surf.open_yarns, name)
            if surfaces:
                surf.write(tmp / f"surfaces_{name}.vtu")
                surf.write(tmp / f"surfaces_{name}.stl")
        if figures and comm.rank == 0:
            painter.collect(tmp)
        times = metrics["time_s"]  # the run's stages, the check's metrics, the outputs
        times["outputs"] = time.perf_counter() - t0
        times["total"] = times.get("total", 0.0) + times.get("metrics", 0.0) + times["outputs"]
        if comm.rank == 0:
            _write_text(tmp / "metrics.json", json.dumps(metrics, indent=1))
    return Path(out)


def write_compaction(run, folder) -> None:
    """folder/compaction.json and compaction.png: the run's compaction curve, each file replaced
    whole (rank 0; also after the run's folder was written, once the curve's permeability is known)."""
    from textile_fenicsx.pipeline.compaction import plot_curve

    assert run.compaction is not None
    folder = Path(folder)
    with atomic_path(folder / "compaction.json") as tmp:
        tmp.write_text(json.dumps(run.compaction.as_dict(), indent=1))
    with atomic_path(folder / "compaction.png") as tmp:
        plot_curve(run.compaction, tmp, f"{run.textile.name}: compaction")


def _write_text(path: Path, text: str) -> None:
    with naming(path):
        path.write_text(text)


FIELD_NAMES = ("w", "z0", "t", "z", "gap_below", "contact")


def _vertex_values(f: dolfinx.fem.Function, cells: np.ndarray, spaces: dict) -> np.ndarray:
    """Values (len(cells), 3) of a Lagrange field at the vertices of the given local cells of its
    (degree-1) mesh, in the geometry dofmap's order (a P1 interpolant is exact at the vertices).
    spaces: the P1 space of each mesh met so far, by id (a yarn's five fields share one: a space
    costs a dofmap, whose index map waits on MPI, 10 ms where the figures' process holds the core)."""
    msh = f.function_space.mesh
    if id(msh) not in spaces:
        spaces[id(msh)] = dolfinx.fem.functionspace(msh, ("Lagrange", 1))
    V1 = spaces[id(msh)]
    f1 = dolfinx.fem.Function(V1)
    f1.interpolate(f)
    return f1.x.array[V1.dofmap.list[cells]]


def yarn_fields(run, k: int):
    """Yarn k's mid-surface fields over its cells in the unit cell (not the ghost strip), at their
    vertices, gathered on rank 0 (collective): (points (N, 3) at x, y, z0 + w, triangles (M, 3),
    {name: values (N,)}) on rank 0, None elsewhere. Points are sorted by x then y, so the file does
    not depend on the number of ranks."""
    from textile_fenicsx.plate.mesh.midsurface import REAL

    y, sol = run.midsurfaces.yarns[k], run.solution
    msh = y.mesh
    n_owned = msh.topology.index_map(2).size_local
    cells = y.cell_kind.indices[(y.cell_kind.values == REAL) & (y.cell_kind.indices < n_owned)]
    nodes = msh.geometry.dofmap[cells]
    ids = msh.geometry.index_map().local_to_global(nodes.ravel().astype(np.int32)).reshape(-1, 3)
    xy = msh.geometry.x[nodes][:, :, :2]
    spaces: dict = {}
    w, z0 = _vertex_values(sol.w[k], cells, spaces), _vertex_values(y.z0, cells, spaces)
    values = {"w": w, "z0": z0, "t": _vertex_values(y.t, cells, spaces), "z": z0 + w,
              "gap_below": _vertex_values(sol.gap[k], cells, spaces),
              "contact": _vertex_values(sol.contact[k], cells, spaces)}
    parts = msh.comm.gather((ids, xy, values), root=0)
    if msh.comm.rank != 0:
        return None
    ids = np.concatenate([p[0] for p in parts]).ravel()
    xy = np.concatenate([p[1] for p in parts]).reshape(-1, 2)
    unique, first, tri = np.unique(ids, return_index=True, return_inverse=True)
    order = np.lexsort((xy[first, 1], xy[first, 0]))  # by x, then y
    rank_of = np.empty_like(order)
    rank_of[order] = np.arange(len(order))
    tri = rank_of[tri.reshape(-1, 3)]
    tri = tri[np.lexsort(np.sort(tri, axis=1).T[::-1])]
    data = {name: np.concatenate([p[2][name] for p in parts]).ravel()[first][order] for name in FIELD_NAMES}
    points = np.column_stack((xy[first][order], data["z"]))
    return points, tri, data


def write_fields(run, folder: Path) -> None:
    """folder/yarn_I.vtu for every yarn I (yarn_fields; collective, rank 0 writes)."""
    import meshio

    comm = run.comm
    if comm.rank == 0:
        with naming(folder):
            folder.mkdir(exist_ok=True)
    for k, y in enumerate(run.midsurfaces.yarns):
        gathered = yarn_fields(run, k)
        if gathered is None:
            continue
        points, tri, data = gathered
        path = folder / f"yarn_{y.yarn}.vtu"
        mesh = meshio.Mesh(points, [("triangle", tri.astype(np.int64))], point_data=data,
                           cell_data={"yarn": [np.full(len(tri), y.yarn, np.int32)]})
        with naming(path):
            meshio.write(path, mesh, file_format="vtu")


def write_failed(run, out) -> Path:
    """A run whose contact iteration failed: `out` holds FAILED (the reason) and log.json (the
    iteration log and the settings), nothing that could be mistaken for a result (collective)."""
    sol, comm = run.solution, run.comm
    document = {"reason": sol.reason, "iterations": sol.iterations, "history": sol.history,
                "parameters": asdict(run.settings.plate), "solver": asdict(run.settings.solver),
                "mesh": asdict(run.settings.mesh), "ranks": comm.size, "versions": versions()}
    with staged_folder(out, comm, remove=RESULT_NAMES) as tmp:
        if comm.rank == 0:
            _write_text(tmp / "FAILED", sol.reason + "\n")
            _write_text(tmp / "log.json", json.dumps(document, indent=1))
    return Path(out)
