"""The projected mesh's arrays as a distributed DOLFINx mesh (DESIGN.md section 4, steps 3-4).

The triangles go to DOLFINx from rank 0 (`create_mesh` with the used nodes only, cell tags by
`distribute_entity_data`, as gmshio does), distributed with shared-facet ghosts (dS forms). Before
that, a ghost strip (copies of the cells along the left and bottom sides, beyond the right and top
sides) gives the periodic seam facets their second neighbour (DESIGN.md sections 6, 11).
"""

from collections.abc import Callable

import numpy as np
from mpi4py import MPI
from scipy.spatial import cKDTree

import dolfinx
from textile_fenicsx.common.errors import GeometryError
from textile_fenicsx.model.textile import Cell

__all__ = ["GHOST", "ghost_strip", "to_dolfinx"]

# Cell tags of the ghost strip: a copy of region k's cells beyond the right/top sides has tag k + GHOST.
GHOST = 10_000_000

def to_dolfinx(comm: MPI.Comm, arrays: tuple | list | None,
               partitioner: Callable) -> tuple[dolfinx.mesh.Mesh, dolfinx.mesh.MeshTags]:
    """A distributed dolfinx mesh and its cell tags from rank 0's (x, cells, tags)."""
    import basix.ufl
    import ufl

    from dolfinx.io.utils import distribute_entity_data

    domain = ufl.Mesh(basix.ufl.element("Lagrange", "triangle", 1, shape=(2,)))
    if comm.rank == 0:
        assert arrays is not None  # rank 0 made them
        x, cells, values = arrays
    else:
        x, cells, values = np.zeros((0, 2)), np.zeros((0, 3), np.int64), np.zeros(0, np.int32)
    msh = dolfinx.mesh.create_mesh(comm, cells, x, domain, partitioner)
    entities, local_values = distribute_entity_data(msh, 2, cells, values)
    msh.topology.create_connectivity(2, 0)
    adj = dolfinx.graph.adjacencylist(entities)
    tags = dolfinx.mesh.meshtags_from_entities(msh, 2, adj, local_values.astype(np.int32))
    tags.name = "covering_set"
    return msh, tags


def ghost_strip(cell: Cell, x: np.ndarray, cells: np.ndarray,
                tags: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh arrays with the ghost strip added (DESIGN.md sections 6 and 11): the cells with an
    edge on the left (bottom) side are copied, shifted by the cell's width (height), beyond the
    right (top) side; a copy reuses the mesh's own nodes on the right (top) side, so the seam facets
    get a neighbour on each side and the solver can put the same facet terms on them as on interior
    facets. A copy of a region-k cell has tag k + GHOST."""
    x0, x1, y0, y1 = cell.bounds
    tol = 1e-9 * max(cell.lx, cell.ly)
    xs, cs, ts, n = [x], [cells], [tags], len(x)
    for axis, lo, hi, length in ((0, x0, x1, cell.lx), (1, y0, y1, cell.ly)):
        if axis == 1 and cell.shift:
            n = _sheared_strip(cell, x, cells, tags, n, (xs, cs, ts), tol)
            continue
        on_lo = np.abs(x[:, axis] - lo) < tol
        on_hi = np.flatnonzero(np.abs(x[:, axis] - hi) < tol)
        pick = on_lo[cells].sum(axis=1) >= 2
        chosen = cells[pick]
        side = np.unique(chosen[on_lo[chosen]])
        inner = np.unique(chosen[~on_lo[chosen]])
        other = 1 - axis  # a side node's partner: the node across the cell at the same coordinate
        if len(side) and len(on_hi):
            dist, k = cKDTree(x[on_hi][:, [other]]).query(x[side][:, [other]])
        else:
            dist, k = np.full(len(side), np.inf), np.zeros(len(side), int)
        if np.any(dist > 10 * tol):
            bad = x[side[np.argmax(dist)]]
            raise GeometryError(f"ghost strip: the boundary node at ({bad[0]:.6f}, {bad[1]:.6f}) mm has no periodic "
                                "partner on the opposite side")
        new = np.full(len(x), -1, np.int64)
        new[side] = on_hi[k]
        new[inner] = n + np.arange(len(inner))
        n += len(inner)
        shift = np.zeros(2)
        shift[axis] = length
        xs.append(x[inner] + shift)
        cs.append(new[chosen])
        ts.append(tags[pick] + GHOST)
    return np.vstack(xs), np.vstack(cs), np.concatenate(ts)


def _sheared_strip(cell: Cell, x: np.ndarray, cells: np.ndarray, tags: np.ndarray, n: int, out: tuple,
                   tol: float) -> int:
    """The strip beyond the top side of a sheared cell (docs/shear.md), appended to out's (nodes,
    cells, tags); returns the node count. A bottom cell's copy moves up by ly and along x by the
    shift, back by whole cells to where its side lies over the top side (the bottom's and the top's
    vertices pair so, periodic_sides.box_with_marks): cells near the split of the top side move
    differently, so an inner node gets a copy per move."""
    x0, y0, y1 = cell.x0, cell.y0, cell.y0 + cell.ly
    on_lo = np.abs(x[:, 1] - y0) < tol
    on_hi = np.flatnonzero(np.abs(x[:, 1] - y1) < tol)
    pick = on_lo[cells].sum(axis=1) >= 2
    chosen = cells[pick]
    side_x = np.where(on_lo[chosen], x[chosen, 0], 0.0).sum(axis=1) / on_lo[chosen].sum(axis=1)
    moves = x0 + np.mod(side_x + cell.shift - x0, cell.lx) - side_x  # per cell: shift - k lx
    moves = cell.shift - cell.lx * np.round((cell.shift - moves) / cell.lx)
    tree = cKDTree(x[on_hi][:, [0]]) if len(on_hi) else None
    copies: dict[tuple[int, float], int] = {}
    xs, cs, ts = out
    new_x, new_cells = [], np.empty_like(chosen)
    for c, (nodes, move) in enumerate(zip(chosen, moves)):
        for k, v in enumerate(nodes):
            if on_lo[v]:
                dist, j = tree.query([x[v, 0] + move]) if tree is not None else (np.inf, 0)
                if dist > 10 * tol:
                    raise GeometryError(f"ghost strip: the boundary node at ({x[v, 0]:.6f}, {x[v, 1]:.6f}) mm has no "
                                        "periodic partner on the opposite side (a sheared cell)")
                new_cells[c, k] = on_hi[int(j)]
                continue
            key = (int(v), round(float(move), 9))
            if key not in copies:
                copies[key] = n
                new_x.append(x[v] + (move, cell.ly))
                n += 1
            new_cells[c, k] = copies[key]
    xs.append(np.array(new_x).reshape(-1, 2))
    cs.append(new_cells)
    ts.append(tags[pick] + GHOST)
    return n
