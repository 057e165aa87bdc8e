"""Where a yarn is corrected: the stations along its path (correct.py samples the displacements
there, and the corrected yarn has a master node and a section at each; verify.py compares the
sections' areas there)."""

import numpy as np

from textile_fenicsx.common import limits
from textile_fenicsx.model.textile import Resolution
from textile_fenicsx.model.yarn import Yarn

__all__ = ["GRADE", "TURN", "budgets", "stations"]

# The correction's stations: the path turns by at most TURN [rad] from one to the next, and the
# distance between neighbours grows by at most GRADE of the distance along the path (so that two
# neighbouring intervals differ by at most about 1.6 x)
TURN = 0.25
GRADE = 0.5
# the fewest stations a yarn is corrected at when the bounds cut every yarn's share
FEWEST = 8


def stations(yarn: Yarn, spacing: float, most: int | None = None) -> np.ndarray:
    """Parameters s of the stations at which the yarn is corrected, and of its corrected nodes:
    at most `spacing` [mm] apart, closer where the path turns (TURN per interval), the distance
    between them graded along the path (GRADE); placed per segment between master nodes, the
    nodes included, so that a yarn continued over periods has the same stations in each.

    The corrected path is a cubic through the stations, parametrised by their index (TexGen's
    interpolation): where the distance between stations jumps, the cubic overshoots. At least
    four stations per segment, the rule before this one, put stations 0.047 mm apart on the
    short segments at the corners of TexGen's orthogonal binders, next to 0.22 mm on the legs:
    the cubic through the input's own points turned at 44/mm where the binder turns at 8.8/mm, and
    its 0.16 mm thick sections folded over each other on the inside of each corner.

    most: the most stations wanted (the ends included); where the rule asks for more, `most` are
    spread over the whole yarn by the same density, the master nodes no longer among them."""
    n = yarn.n_segments
    per = max(16, int(np.ceil(np.max(np.linalg.norm(np.diff(yarn.nodes, axis=0), axis=1)) / (spacing / 8))))
    s = np.linspace(0, n, n * per + 1)
    pos, tan = yarn.centreline(s)
    ds = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    turn = np.arccos(np.clip(np.sum(tan[1:] * tan[:-1], axis=1), -1.0, 1.0))
    h = np.minimum(spacing, TURN * ds / np.maximum(turn, 1e-300))  # per interval of the dense samples
    x = np.concatenate(([0.0], np.cumsum(ds)))
    mid = 0.5 * (x[1:] + x[:-1])
    h = _graded(h, mid, x[-1] if yarn.periodic else None)
    count = np.concatenate(([0.0], np.cumsum(ds / h)))  # intervals wanted up to each dense sample
    ends = np.arange(n + 1) * per
    intervals = np.maximum(1, np.ceil(np.diff(count[ends]) - 1e-9).astype(int))  # per segment
    if most is not None and intervals.sum() + 1 > most:
        return np.interp(np.linspace(0.0, count[-1], max(most, 2)), count, s)
    out = [np.interp(np.linspace(count[a], count[b], m, endpoint=False), count[a:b + 1], s[a:b + 1])
           for a, b, m in zip(ends[:-1], ends[1:], intervals)]
    return np.concatenate(out + [[float(n)]])


def _graded(h: np.ndarray, x: np.ndarray, period: float | None) -> np.ndarray:
    """The largest g <= h with |g(x_i) - g(x_j)| <= GRADE |x_i - x_j| (x increasing; with a
    period, distances also around it)."""
    if period is not None:  # one period either side
        h3, x3 = np.tile(h, 3), np.concatenate((x - period, x, x + period))
        return _graded(h3, x3, None)[len(h):2 * len(h)]
    forward = np.minimum.accumulate(h - GRADE * x) + GRADE * x
    backward = (np.minimum.accumulate((h + GRADE * x)[::-1]))[::-1] - GRADE * x
    return np.minimum(forward, backward)


def budgets(yarns: list[Yarn], spacing: float, section_points: int) -> list[int | None]:
    """Per yarn, the most stations its correction may have (None: no bound reached), so that the
    corrected model, one master node per station, is one the readers take back (limits.py): at
    most MAX_NODES_PER_YARN per yarn, MAX_NODES in all, and surfaces of at most MAX_SURFACE_POINTS
    points as Textile.check_size counts them (4 stations per segment at least, `section_points`
    each, and the 64 a .tg3 is read with). Where the rule asks for more, every yarn's share is cut
    in proportion."""
    wanted = np.array([len(stations(y, spacing)) for y in yarns])
    share = np.minimum(wanted, limits.MAX_NODES_PER_YARN)
    points = 4 * max(section_points, Resolution().section_points)
    total = min(limits.MAX_NODES, limits.MAX_SURFACE_POINTS // points)
    if share.sum() > total:
        share = np.maximum(np.floor(share * (total / share.sum())).astype(int), FEWEST)
    return [int(b) if b < w else None for b, w in zip(share, wanted)]
