"""Point evaluation of mid-surface fields at in-plane points, collective over the ranks."""

import numpy as np
from mpi4py import MPI
from scipy.spatial import cKDTree

import dolfinx
import dolfinx.geometry


def evaluate(f: dolfinx.fem.Function, xy: np.ndarray, comm: MPI.Comm | None = None,
             extrapolate: bool = False) -> np.ndarray:
    """Values of scalar f at in-plane points xy (N, 2), the same on every rank; NaN outside f's mesh,
    or with `extrapolate` the polynomial of the nearest cell there (of the nearest point of it,
    for points farther out than that cell's size).

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
    if extrapolate and np.any(best == comm.size):
        outside = np.flatnonzero(best == comm.size)
        out[outside] = _nearest_cell_values(f, points[outside], tree, comm)
    return out


def _nearest_cell_values(f: dolfinx.fem.Function, points: np.ndarray, tree, comm: MPI.Comm) -> np.ndarray:
    """f at points outside its mesh from the nearest owned cell (collective): that cell's polynomial
    at the point when it lies within the cell's size of it, else at the cell's nearest point."""
    msh = f.function_space.mesh
    n_owned = msh.topology.index_map(2).size_local
    values, dist = np.full(len(points), np.nan), np.full(len(points), np.inf)
    if n_owned:
        midpoints = dolfinx.geometry.create_midpoint_tree(msh, 2, np.arange(n_owned, dtype=np.int32))
        cells = dolfinx.geometry.compute_closest_entity(tree, midpoints, msh, points)
        x = msh.geometry.x
        dofs = msh.geometry.dofmap
        for k, (p, c) in enumerate(zip(points, cells)):
            if c < 0:
                continue
            vertices = x[dofs[c]]
            gap = dolfinx.geometry.compute_distance_gjk(vertices, p)  # from p to the cell's nearest point
            size = np.max(np.linalg.norm(vertices - vertices.mean(axis=0), axis=1))
            dist[k] = np.linalg.norm(gap)
            at = p if dist[k] <= size else p + gap
            values[k] = f.eval(at[None, :], np.array([c], np.int32))[0]
    # the value from the rank whose cell is nearest (lowest rank on ties)
    every = comm.allgather((dist, values))
    d = np.array([e[0] for e in every])
    v = np.array([e[1] for e in every])
    return v[np.argmin(d, axis=0), np.arange(len(points))]


def nearest_images(msh: dolfinx.mesh.Mesh, xy: np.ndarray, periods: tuple[float, float] | np.ndarray) -> np.ndarray:
    """Points xy (N, 2), in the cell already, each moved by whole periods (lx, ly) [mm] to its image
    nearest msh's nodes; a point stays where no image is nearer (collective: the same on every
    rank). A plate that ends on a cell side has no mesh across it, where a point on that side is
    wrapped to: found at the image on the plate's side, it takes the plate's value there, not the
    nearest cell's at the plate's other end."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if np.ndim(periods) == 2:  # the moves themselves, the first none (a sheared cell's Cell.neighbours)
        shifts = np.asarray(periods, float)
    else:
        shifts = np.array([(i * periods[0], j * periods[1]) for i in (0, -1, 1) for j in (0, -1, 1)])
    nodes = msh.geometry.x[:, :2]
    local = np.full((len(shifts), len(xy)), np.inf)
    if len(nodes) and len(xy):
        tree = cKDTree(nodes)
        for k, shift in enumerate(shifts):
            local[k] = tree.query(xy + shift)[0]
    near = np.empty_like(local)
    msh.comm.Allreduce(local, near, op=MPI.MIN)
    return xy + shifts[np.argmin(near, axis=0)]  # the first (no shift) on ties
