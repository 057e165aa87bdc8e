"""Point evaluation of mid-surface fields at in-plane points, collective over the ranks."""

import numpy as np
from mpi4py import MPI

import dolfinx
import dolfinx.geometry


def evaluate(f: dolfinx.fem.Function, xy: np.ndarray, comm: MPI.Comm | None = None) -> np.ndarray:
    """Values of scalar f at in-plane points xy (N, 2), the same on every rank; NaN outside f's mesh.

    Every rank must pass the same points. A point on a rank boundary is taken from the lowest rank
    that holds a cell containing it.
    """
    msh = f.function_space.mesh
    comm = comm or msh.comm
    xy = np.asarray(xy, float).reshape(-1, 2)
    points = np.column_stack((xy, np.zeros(len(xy))))
    n_owned = msh.topology.index_map(2).size_local
    tree = dolfinx.geometry.bb_tree(msh, 2, np.arange(n_owned, dtype=np.int32))
    candidates = dolfinx.geometry.compute_collisions_points(tree, points)
    cells = dolfinx.geometry.compute_colliding_cells(msh, candidates, points)
    found = np.flatnonzero(np.diff(cells.offsets) > 0)
    local = np.full(len(xy), np.nan)
    if len(found):
        first = cells.array[cells.offsets[found]]
        local[found] = f.eval(points[found], first).ravel()
    # lowest rank with a value wins: rank-tagged min over (has value ? rank : size)
    owner = np.where(np.isnan(local), comm.size, comm.rank).astype(np.int32)
    best = np.empty_like(owner)
    comm.Allreduce(owner, best, op=MPI.MIN)
    mine = np.where(best == comm.rank, local, 0.0)
    out = np.empty_like(mine)
    comm.Allreduce(mine, out, op=MPI.SUM)
    out[best == comm.size] = np.nan
    return out
