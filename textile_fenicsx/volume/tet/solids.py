"""The yarn solids of a tet mesh in gmsh's OpenCASCADE kernel (surface_mesh.py drives it).

Each yarn is a chain of its section polygons along its centreline. A periodic yarn's chain is its
stations over whole periods, one chain per lateral copy (a shift by the cell's vectors that is not
along the yarn) that reaches the box, trimmed to the stations that reach it plus a few; a piece
(a yarn that is not periodic) is repeated by the cell's vectors. Every station is one closed
spline through its section points, and a chain the solid through them with ruled faces between
consecutive stations (`addThruSections`, makeRuled): a ruled face depends on its two stations only,
so a chain is exactly periodic, and the box cuts a yarn at x0 and at x0 + lx in the very same
curves moved by the cell vector (a smooth skin through all the stations is fitted globally: the
two cuts of the plain weave differed by 0.7 % in area). Each chain is intersected with the box
alone (its pieces are what of the yarn lies in the cell: the parts that leave through a side are
the next copy's coming back through the opposite one). The faces of those cuts are then
imprinted on the box's faces (copies of them, cut into the box alone: planar, quick), so that
each one lies on the box as a whole face, and the box is fragmented by all the pieces with OCC's
full glue: the arguments share whole faces and nothing else, and OCC does not search every face
of a yarn against the faces of the yarns near it for intersections (there are none:
mesher.py holds a gap between them, and checks.py finds skins that cross in it). With
the partial glue (option 1) this fragment used before, that search was most of the mesher's time:
on the corrected satin the fragment took 99 s with it, 5 s now (one thread, under load; its four
parallel warps alone, 1 s with it); docs/tet_mesh.md.
"""

from __future__ import annotations

import logging

import numpy as np

from textile_fenicsx.model.textile import Textile
from textile_fenicsx.volume.tet import sides

log = logging.getLogger(__name__)

# Stations a periodic yarn's chain goes on beyond the box at each end.
MARGIN = 6
# The most the path turns between two stations [rad]: the ruled skin cuts the inside of a turn.
# Stations 0.25 mm apart and no more cut our orthogonal weave's binders 0.73 % short at their
# turns (0.1-0.2 mm radii); 10 degrees apart as well, 0.07 % (147 stations a period instead of
# 93). The 2D weaves' yarns turn less than that within 0.25 mm: their stations are unchanged.
# (The correction's stations, stations.py, follow turns too, but graded along the path: they move
# every station of the satins and twills, and so their meshes.)
TURN = np.radians(10.0)
# Passes that leave out a station whose skin still folds with stations by spacing alone (a section
# thicker than twice the radius it turns on, between two nodes: the leg fit's corners on
# ortho_w2f3_binder1.375x0.3's gapped solve, where the fold was 124 crossings of the surface mesh)
DROPS = 8
# OCC's glue option for the last fragment (2, full: the arguments share whole faces and do not
# intersect; the pieces lie in the box, and their cut faces are imprinted on its sides first)
GLUE = 2


def yarn_sections(textile: Textile, i: int, spacing: float, points: int, shrink: float = 0.0) -> np.ndarray:
    """Yarn i's section polygons (M, points, 3) [mm] at stations at most `spacing` mm apart over its
    master nodes, and at most TURN apart in the path's direction where that does not fold the
    skin; a station whose skin folds even so is left out, the skin ruled across the turn (one
    period of a periodic yarn: its last section is exactly its first moved by the period); each
    section scaled about its centreline point by (1 - shrink) (0: as modelled)."""
    yarn = textile.yarns[i]
    s = yarn.stations(spacing, minimum_per_segment=1, turn=TURN)
    out = yarn.section_polygons(s, points, 1.0 - shrink)
    folded = np.unique(np.floor(s[:-1][_folds(out)]))
    if len(folded):  # those segments keep their stations by spacing alone
        plain = yarn.stations(spacing, minimum_per_segment=1)
        s = np.sort(np.concatenate([s[~np.isin(np.floor(s), folded)], plain[np.isin(np.floor(plain), folded)]]))
        out = yarn.section_polygons(s, points, 1.0 - shrink)
    for _ in range(DROPS):  # a fold left between two stations: the later one left out, never an end
        folded = np.flatnonzero(_folds(out))
        if not len(folded) or len(s) < 4:
            break
        s = np.delete(s, np.where(folded + 1 < len(s) - 1, folded + 1, folded))
        out = yarn.section_polygons(s, points, 1.0 - shrink)
    if yarn.periodic:
        out[-1] = out[0] + yarn.period
    return out


def _folds(sec: np.ndarray) -> np.ndarray:
    """Which consecutive stations of the sections (M, K, 3) fold the skin ruled between them (M - 1,):
    a section point that does not advance along the mean of the two stations' directions (on the
    inside of a turn tighter than the section is thick; TexGen's refined orthogonal binders with
    stations 10 degrees apart). A folded skin is not a valid solid, and OCC's cuts of one give
    nothing."""
    centre = sec.mean(axis=1)
    tangent = np.gradient(centre, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1), 1e-300)[:, None]
    mean = tangent[1:] + tangent[:-1]
    return np.einsum("mkj,mj->mk", np.diff(sec, axis=0), mean).min(axis=1) <= 0


def section_curve(poly: np.ndarray) -> int:
    """The closed C2 spline through one section's points (K, 3), closed on its first point (its
    OCC curve tag)."""
    import gmsh

    occ = gmsh.model.occ
    tags = [occ.addPoint(*p) for p in poly]
    return occ.addSpline(tags + tags[:1])


# Points at which _z_bounds samples each edge of a skin: on the corrected satin the bounds with 128
# and with 1024 samples differ by 7e-6 mm at most (0.17 s and 0.23 s for all its skins).
EDGE_SAMPLES = 512


def add_skin(sections: np.ndarray, name: str) -> int:
    """The solid through the section polygons (M, K, 3) (its OCC tag): one closed spline per
    station (section_curve), a smooth skin through them, capped by the first and last sections."""
    import gmsh

    occ = gmsh.model.occ
    wires = [occ.addWire([section_curve(poly)]) for poly in sections]
    vols = [t for d, t in occ.addThruSections(wires, makeSolid=True, makeRuled=True) if d == 3]
    if len(vols) != 1:
        raise RuntimeError(f"the skin of {name} gave {len(vols)} solids")
    return vols[0]


def chains(textile: Textile, i: int, lo: np.ndarray, hi: np.ndarray, spacing: float, points: int,
           shrink: float = 0.0, margin: int = MARGIN, legs: bool = False) -> list[np.ndarray]:
    """Yarn i's copies over the box [lo, hi]: section polygons (M, K, 3) [mm] per copy. A periodic
    yarn's copy is a chain of its periods, one per lateral shift by the cell's vectors, trimmed to
    the stations whose sections reach the box plus `margin` stations at each end (so that the box
    cuts its skin where the ends no longer shape it), less the stations beside the box's sides
    (sides.left_out; `legs`: a leg down a side keeps its own); a piece's copies are the
    piece moved by the cell's vectors."""
    yarn = textile.yarns[i]
    one = yarn_sections(textile, i, spacing, points, shrink)
    L = hi - lo
    cellv = np.array([[L[0], 0.0, 0.0], [0.0, L[1], 0.0]])
    span = 3
    shifts: dict[tuple, np.ndarray] = {}
    for a in range(-span, span + 1):
        for b in range(-span, span + 1):
            t = a * cellv[0] + b * cellv[1]
            if yarn.periodic:  # a shift along the yarn is the same chain
                P = yarn.period
                t = t - np.round(t @ P / (P @ P)) * P
            shifts.setdefault(tuple(np.round(t, 9)), t)
    if yarn.periodic:
        P = yarn.period
        reach = int(np.ceil(float(np.linalg.norm(L[:2])) / max(float(np.linalg.norm(P[:2])), 1e-9))) + 2
        one = np.concatenate([one[:-1] + k * P for k in range(-reach, reach)] + [one[-1:] + (reach - 1) * P])
    out = []
    for t in shifts.values():
        sec = one + t
        smin, smax = sec.min(axis=1), sec.max(axis=1)
        meets = np.flatnonzero(np.all((smax[:, :2] >= lo[:2]) & (smin[:, :2] <= hi[:2]), axis=1))
        if len(meets) == 0:
            continue
        if yarn.periodic:
            sec = sec[max(meets[0] - margin, 0):meets[-1] + margin + 1]
            # no station just beside a side of the box that the yarn crosses (sides.py)
            sec = sec[~sides.left_out(sec.mean(axis=1), yarn.period, lo, L, spacing, legs)]
        out.append(sec)
    return out


def build(textile: Textile, lo: np.ndarray, hi: np.ndarray, spacing: float, points: int,
          shrink: float = 0.0, z_pad: float | None = None, legs: bool = False) -> tuple[dict[int, int], list[int]]:
    """The model of the box [lo, hi] with every yarn's pieces in it, fragmented into one
    conforming model (gmsh must be initialised, a model current). Returns volume tag -> phase
    (0 the matrix, 1 + i yarn i), and the yarns whose skins reach the box but which OCC's cut by
    the box left with no piece (it returns nothing for them, without an error). With `z_pad`
    [mm], lo and hi are widened in z, in place, where the skins reach nearer than z_pad to the
    box's top or bottom (a smooth skin swings past its sections at a binder's sharp turn; a skin
    cut by the top face leaves that face unlike the bottom one, and the periodic pairing fails)."""
    import gmsh

    occ = gmsh.model.occ
    skins = [(i, add_skin(sections, y.name)) for i, y in enumerate(textile.yarns)
             for sections in chains(textile, i, lo, hi, spacing, points, shrink, legs=legs)]
    if z_pad is not None and skins:
        z0, z1 = _z_bounds([t for _, t in skins])
        lo[2], hi[2] = min(lo[2], z0 - z_pad), max(hi[2], z1 + z_pad)
    pieces = []
    for i, solid in skins:
        cut, _ = occ.intersect([(3, solid)], [(3, occ.addBox(*lo, *(hi - lo)))])
        pieces += [(i, t) for d, t in cut if d == 3]
    spare = occ.copy([(3, t) for _, t in pieces])  # for the slow fragment, should the quick one fail
    phase = _fragment(_imprinted_box(lo, hi, [t for _, t in pieces]), pieces, GLUE)
    uncarved = sorted({p - 1 for v, p in phase.items() if p and not _carved(v, lo, hi)})
    if uncarved:
        log.warning("tet: OCC's quick fragment (full glue) left the matrix uncarved around %s; fragmenting "
                    "again with the partial glue (slower)", ", ".join(textile.yarns[i].name for i in uncarved))
        occ.remove([(3, v) for v in phase], recursive=True)
        pieces = [(i, t) for (i, _), (_, t) in zip(pieces, spare)]
        phase = _fragment(occ.addBox(*lo, *(hi - lo)), pieces, 1)
    else:
        occ.remove(spare, recursive=True)
        occ.synchronize()
    return phase, sorted({i for i, _ in skins} - {i for i, _ in pieces})


def _fragment(box: int, pieces: list[tuple[int, int]], glue: int) -> dict[int, int]:
    """The box fragmented by the (yarn, piece) pieces with OCC's glue option `glue`: volume tag ->
    phase (0 the matrix, 1 + i yarn i)."""
    import gmsh

    occ = gmsh.model.occ
    old = gmsh.option.getNumber("Geometry.OCCBooleanGlue")
    gmsh.option.setNumber("Geometry.OCCBooleanGlue", glue)
    try:
        _, parts = occ.fragment([(3, box)], [(3, t) for _, t in pieces])
    finally:
        gmsh.option.setNumber("Geometry.OCCBooleanGlue", old)
    occ.synchronize()
    phase = {t: 0 for _, t in parts[0]}
    for (i, _), part in zip(pieces, parts[1:]):
        for _, t in part:
            phase[t] = i + 1
    return phase


def _on_box(face: int, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether a face lies on one of the box's faces (planar, in its plane: where the box cut a yarn)."""
    import gmsh

    if gmsh.model.getType(2, face) != "Plane":
        return False
    b = np.reshape(gmsh.model.occ.getBoundingBox(2, face), (2, 3))
    c = np.asarray(gmsh.model.occ.getCenterOfMass(2, face))
    flat, on = 1e-3 * float(np.max(hi - lo)), 1e-9 * float(np.max(hi - lo))  # OCC pads a face's box
    return any(b[1, ax] - b[0, ax] < flat and min(abs(c[ax] - lo[ax]), abs(c[ax] - hi[ax])) < on for ax in range(3))


def _carved(volume: int, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether every face of a yarn's volume is shared with another volume or lies on the box's faces
    (otherwise the matrix overlaps it: OCC's full glue did not carve the matrix around it)."""
    import gmsh

    for _, f in gmsh.model.getBoundary([(3, volume)], combined=False, oriented=False):
        up, _ = gmsh.model.getAdjacencies(2, f)
        if len(up) < 2 and not _on_box(f, lo, hi):
            return False
    return True


def _imprinted_box(lo: np.ndarray, hi: np.ndarray, pieces: list[int]) -> int:
    """The box [lo, hi] (its OCC tag) with the pieces' faces that lie on its faces (where the box
    cut them) imprinted on those: copies of them, fragmenting the box alone."""
    import gmsh

    occ = gmsh.model.occ
    occ.synchronize()
    faces = [f for _, f in gmsh.model.getBoundary([(3, t) for t in pieces], combined=False, oriented=False)
             if _on_box(f, lo, hi)]
    box = occ.addBox(*lo, *(hi - lo))
    if not faces:
        return box
    out, _ = occ.fragment([(3, box)], occ.copy([(2, f) for f in faces]))
    volumes = [t for d, t in out if d == 3]
    if len(volumes) != 1:
        raise RuntimeError(f"imprinting the cut faces on the box gave {len(volumes)} volumes")
    return volumes[0]


def _z_bounds(solids: list[int], samples: int = EDGE_SAMPLES) -> tuple[float, float]:
    """The solids' lowest and highest z [mm]. A skin is ruled between its sections (add_skin), so z
    is linear along each ruling and its extremes lie on the faces' edges: the section curves and
    the seams, each sampled at `samples` points. (OCC's own boxes of spline solids are loose; its
    boxes from a triangulation (Geometry.OCCBoundsUseStl) took 3.4 s on the corrected satin and
    put its top 1.6e-4 mm below the sampled edges' highest point; these take 0.2 s.)"""
    import gmsh

    gmsh.model.occ.synchronize()
    faces = gmsh.model.getBoundary([(3, t) for t in solids], combined=False, oriented=False)
    edges = {abs(c) for _, c in gmsh.model.getBoundary(faces, combined=False, oriented=False)}
    lowest, highest = np.inf, -np.inf
    for c in edges:
        (a,), (b,) = gmsh.model.getParametrizationBounds(1, c)
        z = np.reshape(gmsh.model.getValue(1, c, np.linspace(a, b, samples)), (-1, 3))[:, 2]
        lowest, highest = min(lowest, float(z.min())), max(highest, float(z.max()))
    return lowest, highest


def periodic_pairs(lo: np.ndarray, hi: np.ndarray, axes: tuple[int, ...], tol: float) -> list:
    """(axis, slave faces, master faces, shift, worst) per periodic axis: each face on the box's +
    side matched to the face on its - side whose bounding box, moved by the box's length along the
    axis, is nearest (within tol [mm]; worst: the largest such distance). OCC's boxes of spline
    faces are loose (and its masses of spline solids off by up to 15 %: not a key), but the same
    cut moved by the cell vector has the same box to round-off."""
    import gmsh

    out = []
    window = 1e-5 * float(np.max(hi - lo))
    def on(ax: int, value: float) -> list[int]:
        a, b = lo - window, hi + window
        a[ax], b[ax] = value - window, value + window
        return [t for _, t in gmsh.model.getEntitiesInBoundingBox(*a, *b, 2)]

    for ax in axes:
        minus, plus = on(ax, lo[ax]), on(ax, hi[ax])
        shift = np.zeros(3)
        shift[ax] = hi[ax] - lo[ax]
        key = {t: np.array(gmsh.model.getBoundingBox(2, t)) for t in minus + plus}
        slaves, masters, worst = [], [], 0.0
        for t in plus:
            want = key[t] - np.r_[shift, shift]
            best = min(minus, key=lambda m: np.abs(key[m] - want).max(), default=None)
            miss = np.inf if best is None else float(np.abs(key[best] - want).max())
            if miss > tol:
                raise RuntimeError(f"face {t} on the + side along {'xyz'[ax]} has no image on the - side "
                                   f"(nearest differs by {miss:.2g} mm)")
            worst = max(worst, miss)
            slaves.append(t)
            masters.append(best)
        if len(set(masters)) != len(masters) or len(masters) != len(minus):
            raise RuntimeError(f"the faces of the two sides along {'xyz'[ax]} do not pair up "
                               f"({len(plus)} + faces, {len(minus)} - faces)")
        log.debug("periodic along %s: %d face pairs, boxes within %.1e mm", "xyz"[ax], len(slaves), worst)
        out.append((ax, slaves, masters, shift, worst))
    return out
