"""Plies (issue 29): N plies of a fabric stacked in one periodic cell, each moved in the plane.

`stack(textile, plies, offsets)` returns one textile whose yarns are the plies' yarns: ply k is the
fabric moved by offsets[k] in the plane and by k times its thickness up (the thickness its yarns'
centrelines and sections span), so that the stacking order between plies is that of the plies at
every point. The whole pipeline runs on it unchanged: the plies meet through the same contact
solve, and the spring that holds yarns together where they are apart draws each ply into the one
below as far as their yarns let it (a ply moved by half a spacing sinks its crowns into the other's
valleys: nesting); a compaction presses the stack. Offsets are given [mm], or drawn at random
in the cell with a seed.
"""

from dataclasses import replace

import numpy as np

from textile_fenicsx.common.errors import TextileError
from textile_fenicsx.common.limits import check_count
from textile_fenicsx.model.textile import Textile

__all__ = ["MAX_PLIES", "ply_of", "random_offsets", "stack"]

MAX_PLIES = 32


def _span(textile: Textile) -> tuple[float, float]:
    """The lowest and highest z of the yarns: their centrelines' extremes -+ their sections' half-heights [mm]."""
    lo, hi = np.inf, -np.inf
    for y in textile.yarns:
        pos, _ = y.centreline(np.linspace(0, y.n_segments, 16 * y.n_segments + 1))
        half = max(s.height for s in y.section.sections()) / 2
        lo, hi = min(lo, float(pos[:, 2].min()) - half), max(hi, float(pos[:, 2].max()) + half)
    return lo, hi


def random_offsets(textile: Textile, plies: int, seed: int) -> list[tuple[float, float]]:
    """The first ply in place, the others moved to uniform random points of the cell [mm]."""
    rng = np.random.default_rng(seed)
    c = textile.cell
    return [(0.0, 0.0)] + [(float(rng.uniform(0, c.lx)), float(rng.uniform(0, c.ly))) for _ in range(plies - 1)]


def stack(textile: Textile, plies: int, offsets: list | None = None) -> Textile:
    """`plies` plies of the fabric in its cell, ply k moved by offsets[k] (dx, dy) [mm] (default:
    none) and by k times the fabric's thickness up; their yarns named "<yarn> (ply k)" from 1."""
    check_count("plies", plies, 1, MAX_PLIES)
    if not textile.cell.periodic:
        raise TextileError(f"{textile.name}: plies are stacked in a periodic cell; this one has free edges")
    if textile.tiling is not None:
        raise TextileError(f"{textile.name}: stack the plies of the unit cell, then repeat the stack")
    given = [(0.0, 0.0)] * plies if offsets is None else [tuple(map(float, o)) for o in offsets]
    if len(given) != plies or any(len(o) != 2 or not np.all(np.isfinite(o)) for o in given):
        raise TextileError(f"ply offsets: give {plies} in-plane offsets (dx, dy) in mm, one per ply, got {given!r}")
    offsets = [(o[0], o[1]) for o in given]
    if plies == 1 and offsets[0] == (0.0, 0.0):
        return textile
    lo, hi = _span(textile)
    yarns = []
    for k, (dx, dy) in enumerate(offsets):
        move = np.array([dx, dy, k * (hi - lo)])
        yarns += [replace(y, nodes=y.nodes + move, name=f"{y.name} (ply {k + 1})") for y in textile.yarns]
    cell = textile.cell
    z_range = None if cell.z_range is None else (cell.z_range[0], cell.z_range[1] + (plies - 1) * (hi - lo))
    return Textile(replace(cell, z_range=z_range), yarns, name=f"{textile.name}_{plies}plies",
                   resolution=textile.resolution, plies=plies)


def ply_of(stacked: Textile) -> list[int]:
    """The ply (0-based) of each yarn of a stack (the yarns come ply by ply)."""
    return [k for k, n in enumerate(stacked.yarns_per_ply()) for _ in range(n)]
