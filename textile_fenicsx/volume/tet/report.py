"""The tet mesh's report (mesher.py makes it): each yarn's volume in the model, enclosed by its
surface (model_volumes, the reference) and read by the model's rays (ray_volumes), against the
volume its tets hold; quality, the contact policy used, fibre angles, phases and periodicity
(mesh_report). LOST: how far a yarn's meshed volume may be off its model's before the mesh fails.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.box import Box, periodic_mismatch
from textile_fenicsx.volume.tet import checks

log = logging.getLogger(__name__)

# A yarn whose meshed volume is off the model's by more than this [%] fails the mesh (OCC's cut of
# a skin by the box can give nothing, and no error: the binders of TexGen's orthogonal weave with
# their stations beside the box's sides kept; the sweep's worst otherwise is 2.5 %).
LOST = 10.0
# section points of the reference volumes: an analytic section's inscribed polygon of 64 points
# holds 0.15 % less than the section (satin4's ellipses), of 512 points 0.01 %
REFERENCE_POINTS = 512


def model_volumes(textile: Textile) -> np.ndarray:
    """Each yarn's volume in the cell [mm^3]: the volume its own surface encloses over its master
    nodes (verify.tube, the divergence theorem, on its sections traced with REFERENCE_POINTS).
    Every yarn lies whole in the box, and a periodic yarn's nodes span one period, which the
    periodic box holds once. The model's vertical rays (metrics, on the 64-point surfaces) converge
    to that surface's volume, at first order where legs are vertical: on the corrected
    ortho_w3f4's binders 400 rays a side read +0.44 %, 800 +0.21 % (docs/tet_mesh.md)."""
    from textile_fenicsx.correction.verify import tube

    fine = replace(textile.resolution, section_points=max(textile.resolution.section_points, REFERENCE_POINTS))
    return np.array([tube(y, fine).volume for y in textile.yarns])


def ray_volumes(textile: Textile, n: int = 400) -> np.ndarray:
    """Each yarn's volume in the cell [mm^3], by the model's vertical rays on an n x n grid."""
    from textile_fenicsx.model.metrics import measure

    return np.array(measure(textile, n=n)["yarn_volume"]["per_yarn"])


def mesh_report(textile, mesh, vol, quality, gamma, contact, gap, options, times, pairs, flipped) -> dict:
    """The mesh report (JSON-ready) of `mesh` (a TetMesh) with its tets' volumes `vol`, gmsh's
    qualities, the contact policy's check (mesher.check_contacts), the gap, the options, the
    times, the periodic face pairs and the tets gmsh gave inverted (`flipped`)."""
    names = mesh.names
    meshed = np.bincount(mesh.phase, weights=vol, minlength=len(names))
    # the model's volumes: of the shrunk sections when the last resort was used
    model, rays = model_volumes(textile), ray_volumes(textile)
    apart = np.abs(rays / np.where(model > 0, model, np.inf) - 1)
    if len(apart) and apart.max() > 0.01:
        k = int(np.argmax(apart))
        log.warning("tet mesh: %s's surface encloses %.4g mm^3 and the model's rays read %.4g: the yarn's volume in "
                    "the cell is uncertain by %.1f %% (its meshed volume is compared with the surface's)",
                    names[1 + k], model[k], rays[k], 100 * apart[k])
    scale = (1 - contact["shrink"]) ** 2
    errors = (meshed[1:] - model * scale) / (model * scale) * 100
    angles = checks.fibre_angles(textile, mesh.points, mesh.tets, mesh.phase, mesh.fibre)
    return {
        "kind": "tet",
        "elements": int(len(mesh.tets)),
        "nodes": int(len(mesh.points)),
        "box_mm": {"lo": mesh.lo.tolist(), "hi": mesh.hi.tolist()},
        "size_mm": options.size,
        "quality": {"measure": "minSICN", "min": float(quality.min()), "mean": float(quality.mean()),
                    "below_0.1": int(np.sum(quality < 0.1)), "gamma_min": float(gamma.min()),
                    "gamma_mean": float(gamma.mean())},
        "inverted_by_gmsh": int(flipped.sum()),
        "smallest_volume_mm3": float(vol.min()),
        "policy": {"name": "gap" if not contact["shrink"] else "shrink",
                   "gap_mm": gap, "least_gap_in_model_mm": contact["least_gap_mm"],
                   "closest_pair": [names[1 + k] for k in contact["pair"]] if contact["pair"] else None,
                   "closest_at_mm": contact["at_mm"], "thinnest_height_mm": contact["thinnest_height_mm"],
                   "shrink_fraction": contact["shrink"],
                   "volume_lost_percent": float(100 * (1 - scale)) if contact["shrink"] else 0.0},
        "volume": {"per_yarn": [{"yarn": names[1 + i], "meshed_mm3": float(meshed[1 + i]), "model_mm3": float(model[i]),
                                 "model_rays_mm3": float(rays[i]), "error_percent": float(errors[i])}
                                for i in range(len(model))],
                   "matrix_mm3": float(meshed[0]), "box_mm3": float(np.prod(mesh.hi - mesh.lo)),
                   "worst_error_percent": float(np.max(np.abs(errors))) if len(errors) else 0.0},
        "fibre_angle_deg": {"p99": float(np.percentile(angles, 99)) if len(angles) else 0.0,
                            "max": float(angles.max()) if len(angles) else 0.0,
                            "within_2deg": float(np.mean(angles <= 2.0)) if len(angles) else 1.0},
        "phases": checks.phase_mismatch(textile, mesh.points, mesh.tets, mesh.phase),
        "periodicity": {**periodic_mismatch(mesh.points, Box(tuple(mesh.lo), tuple(mesh.hi))),
                        "face_pairs": {"xyz"[p[0]]: len(p[1]) for p in pairs}},
    }
