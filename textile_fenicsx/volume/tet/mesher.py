"""The conforming, periodic tet mesh of a unit cell: matrix and yarns (gmsh OpenCASCADE).

Policy for yarns in contact (docs/tet_mesh.md has the measurements behind it): the yarns of a
corrected model touch at zero gap, and two solids that touch over an area cannot be meshed with
tets of bounded quality (the matrix between them is a wedge of zero angle where they part). So the
mesher needs a gap of matrix between every two yarns, at least `TetOptions.gap` [mm] (default 5 %
of the thinnest yarn's height), which the solve holds (`textile-fenicsx solve --min-gap G`,
SolverOptions.min_gap: the exact contact method keeps every contact node's gap >= G with the
sections unchanged, so no yarn volume is lost). The gap sheets are meshed with elements fitted to
them: the size at a point is `grading` x (its distance to the nearest yarn + its distance to the
nearest other yarn), between `smallest` and `size`, on a grid given to gmsh as a background field.
A model whose yarns overlap (deeper than 1 % of the thinnest yarn's height) is refused, naming the
pair, the place and the depth; one whose yarns are closer than 0.75 x the gap is refused too,
pointing to `solve --min-gap`, unless `shrink` is asked for: the last resort, every section scaled
about its centreline by the factor that opens the gap, and the volume lost reported.

The box is the cell in x, y and the yarns' own z extent padded by gap / 2 above and below (a stack
of identical plies is then separated by the gap, like yarns), or `z_range` (a mould's). The mesh
is periodic in x, y and z: gmsh copies the mesh of each - face onto its + face (`setPeriodic`),
and the + face's nodes are then put exactly on their partners' images.

gmsh runs on rank 0 only; the arrays are returned there (None on the other ranks); an error is
raised on every rank.
"""

from __future__ import annotations

import logging
import tempfile
import time
from dataclasses import replace

import numpy as np
from mpi4py import MPI

from textile_fenicsx.common.errors import GeometryError, MeshError, TextileError
from textile_fenicsx.common.parallel import wait_asleep
from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.tet import checks
from textile_fenicsx.volume.tet.elements import FlatTets, fibre_directions, refuse_flat, snap_periodic
from textile_fenicsx.volume.tet.options import TetMesh, TetOptions, default_gap, thinnest_height
from textile_fenicsx.volume.tet.report import LOST, mesh_report
from textile_fenicsx.volume.tet.surface_mesh import session
from textile_fenicsx.volume.tet.volume_mesh import generate

log = logging.getLogger(__name__)

# Overlap the mesher accepts, as a fraction of the thinnest yarn's height (the solve's check: verify.py).
OVERLAP_TOLERANCE = 0.01
# The least gap the mesher accepts, as a fraction of the gap asked for: the solve holds the gap at
# its nodes, and between them the gap dips by the P2 field's error (to 0.91 G on the lenticular satin).
ACCEPT = 0.75
# The size, as a fraction of the one asked for, a mesh with flat tets inside the box is made again
# at, once. gmsh's optimisers (and Relocate3D again) leave a flat tet whose four nodes all lie on a
# yarn's surface: binder1.375's gapped corrected model at 0.35 mm, two in the matrix (1.1e-10 mm^3)
# with two nodes on a seam of a binder's skin and two on the face beside it; at 0.3 mm none.
FLAT_RETRY = 0.85


def check_contacts(textile: Textile, gap: float, shrink: bool, n: int = 200) -> dict:
    """The policy's check before meshing: refuse overlapping yarns; yarns closer than `gap` are
    refused too, or (shrink) get the section scale that opens it. Returns the measured gap, the
    pair, the place and the shrink fraction (0: none)."""
    height = thinnest_height(textile)
    g = checks.yarn_gaps(textile, n)
    info = {"least_gap_mm": g["gap"], "pair": g["pair"], "at_mm": g["at"], "thinnest_height_mm": height,
            "shrink": 0.0}
    if g["pair"] is None:
        return info
    a, b = (textile.yarns[k].name for k in g["pair"])
    where = "(" + ", ".join(f"{v:.3f}" for v in g["at"]) + ") mm"
    if g["gap"] < -OVERLAP_TOLERANCE * height:
        raise GeometryError(f"{a} and {b} overlap at {where}, {-g['gap']:.4f} mm deep (more than "
                            f"{OVERLAP_TOLERANCE:.0%} of the thinnest yarn's height, {height:.3f} mm): a tet mesh "
                            "needs yarns apart; correct the model with `textile-fenicsx solve --min-gap G` "
                            "first, or mesh it with --kind voxel")
    if g["gap"] < ACCEPT * gap:
        if not shrink:
            raise GeometryError(f"{a} and {b} are {g['gap']:.4f} mm apart at {where}, less than the gap the tet "
                                f"mesh needs ({gap:.4f} mm): solve with `textile-fenicsx solve --min-gap {gap:.3g}`, "
                                "or allow shrinking the sections (the volume lost is reported), or use --kind voxel")
        # sections scaled by (1 - s) move each surface by about s x its half height: open the gap
        info["shrink"] = float(min(0.5, (gap - g["gap"]) / height))
        log.warning("tet: %s and %s are %.4f mm apart at %s: sections shrunk by %.2f %% to open a %.4f mm gap",
                    a, b, g["gap"], where, 100 * info["shrink"], gap)
    return info


def tet_mesh(textile: Textile, options: TetOptions = TetOptions(), comm: MPI.Comm = MPI.COMM_WORLD) -> TetMesh | None:
    """The cell's conforming periodic tet mesh (on rank 0; None on the other ranks). Raises the same
    TextileError on every rank if the model is refused or gmsh fails (never hangs)."""
    result: TetMesh | None = None
    error: Exception | None = None
    if comm.rank == 0:
        try:
            result = _flat_retried(textile, options)
        except (TextileError, MeshError) as e:
            error = e
        except Exception as e:  # gmsh's own errors, reported on every rank
            error = MeshError(f"gmsh could not make the tet mesh of {textile.name!r}: {e}; try another --size or "
                              "--gap, or --kind voxel")
    wait_asleep(comm)  # the other ranks leave rank 0's gmsh threads the cores
    error = comm.bcast(error, root=0)
    if error is not None:
        raise error
    return result


def _flat_retried(textile: Textile, options: TetOptions) -> TetMesh:
    """_tet_mesh; where gmsh's mesh has flat tets inside the box, made once more at FLAT_RETRY x
    the size (the report's size_mm is the one used)."""
    try:
        return _tet_mesh(textile, options)
    except FlatTets as e:
        if not e.inside:
            raise
        smaller = replace(options, size=FLAT_RETRY * options.size)
        log.warning("tet: %s: meshed again at size %.4g mm", str(e).split(";")[0], smaller.size)
        try:
            return _tet_mesh(textile, smaller)
        except FlatTets as again:
            raise FlatTets(f"{again} (at size {smaller.size:.4g} mm, and at {options.size:.4g} mm before)") from None


def _tet_mesh(textile: Textile, options: TetOptions) -> TetMesh:
    import gmsh

    start = time.perf_counter()
    if not textile.cell.periodic:
        raise TextileError(f"{textile.name!r}: a tet mesh is made of a periodic cell; this one has free edges")
    height = thinnest_height(textile)
    gap = default_gap(textile, options)
    contact = check_contacts(textile, gap, options.shrink)
    shrink = contact["shrink"]
    times: dict[str, float] = {}
    initialised = gmsh.isInitialized()
    if not initialised:
        gmsh.initialize(interruptible=False)
    added = False
    try:
        session(options)
        gmsh.model.add(f"tet-{textile.name}")
        added = True
        with tempfile.TemporaryDirectory(prefix="tet-sizes-") as folder:
            arrays, lo, hi, pairs, traced, curvature = generate(textile, options, gap, shrink, height, times, folder)
        points, tets, phase, faces = arrays
        elements = gmsh.model.mesh.getElementsByType(4)[0]
        quality = gmsh.model.mesh.getElementQualities(elements, "minSICN")
        gamma = gmsh.model.mesh.getElementQualities(elements, "gamma")
    finally:
        if added:
            gmsh.model.remove()
        if not initialised:
            gmsh.finalize()
    t = time.perf_counter()
    snapped = snap_periodic(points, lo, hi, faces)
    vol = checks.signed_volumes(points, tets)
    flip = vol < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    vol = np.abs(vol)
    refuse_flat(textile.name, points, tets, vol, lo, hi)
    fibre = fibre_directions(textile, points, tets, phase)
    mesh = TetMesh(points, tets, phase, fibre, lo, hi, ["matrix"] + [y.name for y in textile.yarns])
    mesh.report = mesh_report(textile, mesh, vol, quality, gamma, contact, gap, options, times, pairs, flip)
    mesh.report["sections_retraced"] = traced
    mesh.report["curvature_per_2pi"] = curvature
    mesh.report["box_moved_mm"] = [float(lo[0] - textile.cell.x0), float(lo[1] - textile.cell.y0)]
    mesh.report["periodicity"]["snapped_mm"] = snapped
    times["checks_s"] = time.perf_counter() - t
    mesh.report["times_s"] = {**times, "total": time.perf_counter() - start}
    r = mesh.report
    lost = max(r["volume"]["per_yarn"], key=lambda y: abs(y["error_percent"]), default=None)
    if lost is not None and abs(lost["error_percent"]) > LOST:
        raise MeshError(f"the tet mesh of {textile.name!r} holds {lost['meshed_mm3']:.4g} mm^3 of {lost['yarn']} "
                        f"where the model has {lost['model_mm3']:.4g} ({lost['error_percent']:+.1f} %): OCC's cut "
                        "of its skin by the box lost it; use --kind voxel")
    log.info("tet: %d tets, %d nodes, quality (minSICN) min %.3f mean %.3f, yarn volume error worst %.2f %%, "
             "periodic %s, %.1f s", r["elements"], r["nodes"], r["quality"]["min"], r["quality"]["mean"],
             r["volume"]["worst_error_percent"], r["periodicity"]["periodic"], r["times_s"]["total"])
    return mesh
