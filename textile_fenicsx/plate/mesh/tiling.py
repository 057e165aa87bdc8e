"""A coupon's projected mesh: its unit cell's mesh repeated (DESIGN.md section 4).

A coupon made by `coupon.tile` is not meshed by gmsh as a whole: its unit cell is, and the unit
cell's triangles are repeated nx x ny times (the periodic sides match node for node), each cell
going to the copy of its yarns whose centreline is nearest. Every repeat then has the same mesh,
and a periodic coupon's solution repeats the unit cell's to round-off.
"""

import numpy as np
import scipy.sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from textile_fenicsx.common.errors import GeometryError
from textile_fenicsx.model.textile import Textile

__all__ = ["tile_arrays"]


def tile_arrays(x: np.ndarray, cells: np.ndarray, tags: np.ndarray, coverage: dict,
                coupon: Textile) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """The unit cell's mesh arrays repeated over a coupon made by `coupon.tile`: coincident nodes
    on the repeats' common sides merged, each cell's unit-cell yarns replaced by the coupon's
    copies of them whose centrelines are nearest. Returns the coupon's arrays and coverage."""
    tiling = coupon.tiling
    assert tiling is not None  # a coupon made by coupon.tile
    unit = tiling.unit.cell
    shifts = [(i * unit.lx, j * unit.ly) for i in range(tiling.nx) for j in range(tiling.ny)]
    X = np.vstack([x + s for s in shifts])
    C = np.vstack([cells + r * len(x) for r in range(len(shifts))])
    T = np.tile(tags, len(shifts))
    # nodes of neighbouring repeats on their common side coincide (to round-off): one node each
    tol = 1e-9 * max(coupon.cell.lx, coupon.cell.ly)
    same = cKDTree(X).query_pairs(tol, output_type="ndarray")
    graph = scipy.sparse.coo_matrix((np.ones(len(same)), (same[:, 0], same[:, 1])), shape=(len(X), len(X)))
    _, label = connected_components(graph, directed=False)
    first = np.unique(label, return_index=True)[1]
    X, C = X[first], label[C]
    # unit yarn k over a cell -> the copy of k nearest to the cell's centre
    centre = X[C].mean(axis=1)
    copies: dict[int, list[int]] = {}
    for i, k in enumerate(tiling.source):
        copies.setdefault(k, []).append(i)
    covering: list[list[int]] = [[] for _ in range(len(C))]
    for k, candidates in copies.items():
        over = np.flatnonzero(np.isin(T, [t for t, yarns in coverage.items() if k in yarns]))
        if len(over) == 0:
            continue
        d = np.column_stack([np.linalg.norm(coupon.nearest_centreline(c, centre[over])[0][:, :2] - centre[over], axis=1)
                             for c in candidates])
        order = np.argsort(d, axis=1)
        rows = np.arange(len(over))
        best = d[rows, order[:, 0]]
        second = d[rows, order[:, 1]] if len(candidates) > 1 else np.full(len(over), np.inf)
        if np.any(best > 0.5 * second):
            m = int(np.argmax(best / second))
            raise GeometryError(f"coupon mesh: the cell at ({centre[over[m], 0]:.3f}, {centre[over[m], 1]:.3f}) mm is "
                                f"nearly as close to two copies of {tiling.unit.yarns[k].name}; cannot tell "
                                "which covers it")
        for cell_index, c in zip(over, np.asarray(candidates)[order[:, 0]]):
            covering[cell_index].append(int(c))
    sets = [tuple(sorted(c)) for c in covering]
    tag_of = {s: t + 1 for t, s in enumerate(sorted(set(sets)))}
    return X, C, np.array([tag_of[s] for s in sets], np.int32), {t: s for s, t in tag_of.items()}


