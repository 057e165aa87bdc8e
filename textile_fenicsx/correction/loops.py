"""Loops taken out of a yarn's master nodes before it is meshed (issue 27; DESIGN.md 4, step 2).

TexGen's layer-to-layer weave with a binder wider than the gap between two weft columns places
the binder's leg nodes past each other at one height: x 5.64 then 5.56 mm, both at z 1.45, where
the column's gap is at 5.60. That is its way of giving a thick binder room, not a path: the path
runs 0.08 mm back and turns by about 150 degrees twice within 0.2 mm for a section 0.3 mm thick.
Such a stretch is no plate (two heights over one place): legs.py cut it out as a leg, and the
correction's stations crowded into the loop, their frames swung, and the corrected binders folded
5.95 % of their volume with sections crossing themselves (docs/sweep.md).

So, before the plates are made, every yarn's master nodes are walked in the direction the yarn
runs in plan (its period; a yarn that is not periodic: first to last node), and each run of nodes
that goes back is pooled with its neighbours until their mean position along that direction runs
forward (pool adjacent violators). A pool whose nodes, each moved along the direction to the
pool's mean, meet at one place (within MERGE_TOL, height and offset across included) becomes one
node there: TexGen's crossed pair becomes one node in the column's gap. It keeps its first node's
section, up vector and angle; a section inside the merged segment is dropped. A pool at several
heights is left as it is: TexGen's wide-binder orthogonal weave crosses its leg nodes from
z 0.15 to 1.45, a vertical leg leaning back 0.08 mm, which is a leg anyway (legs.py) and which
leg_fit places (measured: made vertical, its 1.375 mm binder's corrected leg then overlapped a weft
0.021 mm deep; as TexGen wrote it, the weave passes).
"""

import logging
from dataclasses import replace

import numpy as np
from scipy.optimize import isotonic_regression

from textile_fenicsx.model.textile import Textile
from textile_fenicsx.model.yarn import NodeSections, Yarn

__all__ = ["MERGE_TOL", "unlooped", "unlooped_yarn"]

log = logging.getLogger(__name__)

# nodes a pool brings closer than this [mm] are one node
MERGE_TOL = 1e-3


def _pools(t: np.ndarray) -> list[tuple[int, int, float]]:
    """Pool adjacent violators (scipy's isotonic regression): [(first, end, mean), ...] over t,
    whose means do not decrease."""
    fit = isotonic_regression(t)
    return [(int(a), int(b), float(fit.x[a])) for a, b in zip(fit.blocks[:-1], fit.blocks[1:])]


def _node_sections(section, members: list, periodic: bool):
    """The yarn's sections on the new nodes (members[j]: the old nodes new node j stands for, its
    section its first's; a periodic yarn's last new node repeats its first): a mid-section stays
    where its old segment still joins two new nodes next to each other."""
    if not isinstance(section, NodeSections):
        return section
    unique = len(members) - 1 if periodic else len(members)
    n = len(section.at_nodes) - 1 if periodic else len(section.at_nodes)  # a periodic yarn's old node n is 0
    where = {k: j for j, ks in enumerate(members[:unique]) for k in ks}
    mid = []
    for k, t, sec in section.mid:
        a, b = where[k % n], where[(k + 1) % n]
        if b == a + 1 or (periodic and a == unique - 1 and b == 0):
            mid.append((a, t, sec))
    return replace(section, at_nodes=tuple(section.at_nodes[ks[0]] for ks in members), mid=tuple(mid))


def unlooped_yarn(yarn: Yarn) -> tuple[Yarn, list[str]]:
    """The yarn with its master nodes running forward in plan (module doc), and what moved (one
    line per pool; [] and the yarn itself where nothing runs back)."""
    ahead = (yarn.period if yarn.periodic else yarn.nodes[-1] - yarn.nodes[0])[:2]
    length = float(np.linalg.norm(ahead))
    if length == 0:
        return yarn, []
    d = ahead / length
    n = len(yarn.nodes) - 1 if yarn.periodic else len(yarn.nodes)
    start = 0
    if yarn.periodic:  # start the walk after its longest step ahead: no loop spans that
        t = np.r_[yarn.nodes[:n, :2] @ d, yarn.nodes[0, :2] @ d + length]
        start = (int(np.argmax(np.diff(t))) + 1) % n
    order = (start + np.arange(n)) % n
    lapped = yarn.nodes[order] + np.outer(order < start, yarn.period)  # a period on, past the last node
    t = lapped[:, :2] @ d
    nodes, members, moved = [], [], []
    for a, b, mean in _pools(t):
        p = lapped[a:b] + np.outer(mean - t[a:b], np.r_[d, 0.0])
        if b - a > 1 and float(np.max(np.ptp(p, axis=0))) < MERGE_TOL:  # a step back at one height
            nodes.append(p.mean(axis=0))
            members.append(list(order[a:b]))
            x, y, z = nodes[-1] - (yarn.period if order[a] < start else 0.0)
            moved.append(f"master nodes {', '.join(map(str, order[a:b]))} step {np.ptp(t[a:b]):.3g} mm back: "
                         f"one node at ({x:.4g}, {y:.4g}, {z:.4g}) mm")
        else:  # (a leg leaning back stays: it is no plate, and leg_fit places it)
            nodes += list(lapped[a:b])
            members += [[k] for k in order[a:b]]
    if not moved:
        return yarn, []
    new = np.array(nodes)
    if yarn.periodic:  # the nodes a period on back in front, the first node repeated a period on
        lap = [j for j, ks in enumerate(members) if ks[0] < start]
        j0 = lap[0] if lap else 0
        new = np.vstack((new[j0:] - (yarn.period if lap else 0.0), new[:j0]))
        members = members[j0:] + members[:j0]
        new = np.vstack((new, new[0] + yarn.period))
        members.append(members[0])
    rows = [ks[0] for ks in members]

    def pick(v):
        return None if v is None else v[rows]

    return replace(yarn, nodes=new, tangents=pick(yarn.tangents), ups=pick(yarn.ups), angles=pick(yarn.angles),
                   section=_node_sections(yarn.section, members, yarn.periodic)), moved


def unlooped(textile: Textile) -> tuple[Textile, tuple[int, ...]]:
    """The textile with every yarn's loops taken out (module doc), and the yarns that had one; the
    textile itself where none has."""
    yarns, changed = [], []
    for i, yarn in enumerate(textile.yarns):
        new, moved = unlooped_yarn(yarn)
        yarns.append(new)
        if moved:
            changed.append(i)
            log.info("loops: %s runs back in plan: %s", yarn.name, "; ".join(moved))
    if not changed:
        return textile, ()
    return replace(textile, yarns=yarns), tuple(changed)
