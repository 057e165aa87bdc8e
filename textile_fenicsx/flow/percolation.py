"""The pores' pockets and the directions they percolate in, on the periodic cell (impermeable yarns).

The pressure's nodes in the pores form a graph: two nodes are joined where they share a pore cell,
and a node on a + face is joined to its image on the - face (one period along the axes it was
wrapped on). Each connected part is a pocket of fluid whose pressure is defined up to its own
constant: one node of each is held. A pocket percolates along an axis where the graph has a cycle
that goes round the cell along it: a spanning tree gives each node its period (an integer vector,
the copy of the cell it is in), and an edge outside the tree that joins two nodes whose periods
differ by other than its own wrap closes such a cycle. Along an axis no pocket percolates in, no
fluid crosses the cell: the cell's permeability there is 0.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

__all__ = ["pockets"]


def pockets(cells: np.ndarray, slaves: np.ndarray, masters: np.ndarray,
            wraps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cells (n, k): the pressure nodes of each pore cell (any integer labels); slaves and masters
    (m,): a + face node and its image, wrapped by the integer vectors wraps (m, 3) (1 along an axis
    it was brought back over). Returns a node held in each pocket (the smallest that is no slave)
    and whether any pocket percolates along x, y, z (3,)."""
    nodes, inverse = np.unique(np.concatenate([cells.ravel(), slaves, masters]), return_inverse=True)
    n = len(nodes)
    cell_nodes = inverse[: cells.size].reshape(cells.shape)
    pairs = inverse[cells.size:].reshape(2, -1)
    # edges: each cell's nodes to its first (period 0), each slave to its master (its wrap)
    a = np.concatenate([np.repeat(cell_nodes[:, 0], cells.shape[1] - 1), pairs[0]])
    b = np.concatenate([cell_nodes[:, 1:].ravel(), pairs[1]])
    shift = np.concatenate([np.zeros((len(a) - len(pairs[0]), 3), np.int64), np.asarray(wraps, np.int64)])
    count, label = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)
    is_slave = np.zeros(n, bool)
    is_slave[pairs[0]] = True
    held = np.full(count, np.iinfo(np.int64).max)
    candidates = np.flatnonzero(~is_slave)
    np.minimum.at(held, label[candidates], nodes[candidates])
    # each node's period, along a spanning forest: a root joined to the first node of every pocket
    first = np.full(count, -1)
    first[label[::-1]] = np.arange(n)[::-1]
    root = n
    a_all = np.concatenate([a, b, np.full(count, root)])
    b_all = np.concatenate([b, a, first])
    s_all = np.concatenate([shift, -shift, np.zeros((count, 3), np.int64)])
    order, parent = breadth_first_order(coo_matrix((np.arange(1, len(a_all) + 1), (a_all, b_all)),
                                                   shape=(n + 1, n + 1)).tocsr(), root, directed=True)
    step = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(a_all, b_all))}
    period = np.zeros((n + 1, 3), np.int64)
    for node in order[1:]:
        period[node] = period[parent[node]] + s_all[step[(int(parent[node]), int(node))]]
    closing = period[b] - period[a] - shift  # 0 on every edge unless its cycle goes round the cell
    percolates = np.any(closing != 0, axis=0)
    return held[held < np.iinfo(np.int64).max], percolates
