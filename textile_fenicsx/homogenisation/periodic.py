"""Periodicity of a box cell: the node check, the multi-point constraint and the pinned point.

Every dof on a + face (x = hi in any coordinate) is a slave of the dof at its image with ALL its +
coordinates wrapped at once (matched by location, coefficient 1): a point on the x+ face maps to
the x- face, one on the x+ y+ edge to the x- y- edge, the + + + corner to the - - - corner. No
master then lies on a + face, so no slave is another slave's master (dolfinx_mpc does not resolve
such chains, DESIGN.md 12) and each slave has exactly one master, provided the mesh's nodes are
periodic, which `check_node_periodicity` checks first (numpy/scipy only: no DOLFINx).
"""

from __future__ import annotations

import dolfinx_mpc
import numpy as np
from mpi4py import MPI
from scipy.spatial import cKDTree

import dolfinx
from textile_fenicsx.common.errors import GeometryError
from textile_fenicsx.volume.box import Box, periodic_mismatch

__all__ = ["Box", "bounding_box", "check_node_periodicity", "check_one_master", "periodic_constraint", "pin"]


def bounding_box(mesh: dolfinx.mesh.Mesh, rtol: float = 1e-7) -> Box:
    """The mesh's bounding box over all ranks; tol = rtol x its largest side."""
    x = mesh.geometry.x[: mesh.geometry.index_map().size_local]
    lo, hi = np.empty(3), np.empty(3)
    mesh.comm.Allreduce(x.min(axis=0) if len(x) else np.full(3, np.inf), lo, op=MPI.MIN)
    mesh.comm.Allreduce(x.max(axis=0) if len(x) else np.full(3, -np.inf), hi, op=MPI.MAX)
    return Box(tuple(float(v) for v in lo), tuple(float(v) for v in hi), rtol * float(np.max(hi - lo)))


def _on_plus(x: np.ndarray, box: Box) -> np.ndarray:
    """(3, n) points -> (3, n) booleans: on the + face of each axis."""
    return np.abs(x - np.asarray(box.hi)[:, None]) < box.tol


def check_node_periodicity(points: np.ndarray, box: Box, what: str = "mesh") -> None:
    """Raise GeometryError unless every point lies in the box and every point on a face of the box
    has its image across it, within box.tol (meshes.volume.periodic_mismatch).

    points (n, 3): all the nodes (or dof locations).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    lo, hi = np.asarray(box.lo), np.asarray(box.hi)
    outside = np.any((points < lo - box.tol) | (points > hi + box.tol), axis=1)
    if np.any(outside):
        raise GeometryError(f"{what}: {int(outside.sum())} node(s) outside the periodic box {_point(lo)} - "
                            f"{_point(hi)}, e.g. {_point(points[outside][0])}")
    report = periodic_mismatch(points, box, tol=box.tol / float(np.max(box.size)))
    if not report["periodic"]:
        axis = next(a for a in "xyz" if report[a]["missing"] or report[a]["plus"] != report[a]["minus"])
        r = report[axis]
        example = f", e.g. {_point(r['example'])}" if r["example"] is not None else ""
        raise GeometryError(f"{what} is not periodic: on the {axis} faces {r['missing']} of {r['plus']} node(s) of "
                            f"the + face have no image on the - face ({r['minus']} nodes there) within "
                            f"{box.tol:.3g} mm{example}")


def _point(x) -> str:
    return "(" + ", ".join(f"{float(v):.9g}" for v in x) + ")"


def _dof_points(V: dolfinx.fem.FunctionSpace) -> np.ndarray:
    """Locations of the owned dof blocks of V (n, 3)."""
    return V.tabulate_dof_coordinates()[: V.dofmap.index_map.size_local]


def periodic_constraint(V: dolfinx.fem.FunctionSpace, box: Box) -> dolfinx_mpc.MultiPointConstraint:
    """The finalised constraint v(x) = v(wrap(x)) for every dof on a + face (collective).

    Checks first that the dof locations are periodic (GeometryError otherwise). Each slave's master
    is the dof AT its wrapped location, matched by coordinates over all ranks' face dofs, with
    coefficient 1: dolfinx_mpc's geometric constraint instead evaluates the basis functions at the
    wrapped point and keeps every value over 1e-13, which rounding exceeds on fine meshes (a 600k
    dof box of 11.2 mm gave 588 nodes a second master of ~1e-13). `check_one_master` confirms.
    """
    comm = V.mesh.comm
    imap, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    points = _dof_points(V)
    lo, hi = np.asarray(box.lo), np.asarray(box.hi)
    on_face = np.flatnonzero(np.any((np.abs(points - lo) < box.tol) | (np.abs(points - hi) < box.tol), axis=1))
    face_points = np.concatenate(comm.allgather(points[on_face]))
    face_blocks = np.concatenate(comm.allgather(imap.local_range[0] + on_face.astype(np.int64)))
    face_owners = np.concatenate([np.full(len(b), r, np.int32) for r, b in enumerate(comm.allgather(on_face))])
    check_node_periodicity(face_points, box, "the mesh's dof locations")
    # slaves: owned blocks, then ghost blocks (dolfinx_mpc wants a rank's ghost slaves too)
    local = V.tabulate_dof_coordinates()
    slave_blocks = np.flatnonzero(np.any(_on_plus(local.T, box), axis=0))
    wrapped = local[slave_blocks] - _on_plus(local[slave_blocks].T, box).T * box.size
    distance, nearest = cKDTree(face_points).query(wrapped, distance_upper_bound=box.tol) if len(wrapped) \
        else (np.zeros(0), np.zeros(0, np.int64))
    if not np.all(np.isfinite(distance)):  # cannot happen after the check; kept as a guard
        raise GeometryError("periodic constraint: a + face dof has no dof at its image")
    component = np.arange(bs)
    slaves = (slave_blocks[:, None] * bs + component).ravel().astype(np.int32)
    masters = (face_blocks[nearest][:, None] * bs + component).ravel().astype(np.int64)
    owners = np.repeat(face_owners[nearest], bs).astype(np.int32)
    mpc = dolfinx_mpc.MultiPointConstraint(V)
    mpc.add_constraint(V, slaves, masters, np.ones(len(slaves), dtype=dolfinx.default_scalar_type), owners,
                       np.arange(len(slaves) + 1, dtype=np.int32))
    mpc.finalize()
    owned = int(np.count_nonzero(slave_blocks < imap.size_local)) * bs
    check_one_master(mpc, comm.allreduce(owned, op=MPI.SUM))
    return mpc


def check_one_master(mpc: dolfinx_mpc.MultiPointConstraint, expected: int | None = None) -> int:
    """Raise GeometryError unless every owned slave has exactly one master with coefficient 1 (and,
    if given, the slaves number `expected` over all ranks); returns the number of slaves (collective)."""
    comm = mpc.V.mesh.comm
    n_owned = mpc.V.dofmap.index_map.size_local * mpc.V.dofmap.index_map_bs
    slaves = np.asarray(mpc.slaves)
    slaves = slaves[slaves < n_owned]
    offsets = np.asarray(mpc.masters.offsets)
    coeffs, _ = mpc.coefficients()
    counts = offsets[slaves + 1] - offsets[slaves]
    ones = counts == 1
    good = ones.copy()
    good[ones] = np.abs(coeffs[offsets[slaves[ones]]] - 1.0) < 1e-10
    bad = comm.allreduce(int((~good).sum()), op=MPI.SUM)
    total = comm.allreduce(len(slaves), op=MPI.SUM)
    if bad:
        raise GeometryError(f"periodic constraint: {bad} of {total} slave dofs do not have exactly one master "
                            "with coefficient 1 (the mesh's faces do not match)")
    if expected is not None and total != expected:
        raise GeometryError(f"periodic constraint: {total} slave dofs, but {expected} dofs lie on the + faces")
    return total


def pin(V: dolfinx.fem.FunctionSpace, box: Box) -> dolfinx.fem.DirichletBC:
    """Zero Dirichlet condition on the dof block at the mesh vertex nearest the box's centre (never
    on a + face): fixes the translation the periodic fluctuation is defined up to. A vertex, so that
    every degree on the mesh pins the same point (the P1 level of pmultigrid.py is then a subspace
    of the P2 problem). Every rank that holds the block (owned or ghost) gets it, so that the
    condition is applied consistently (collective)."""
    comm = V.mesh.comm
    imap = V.dofmap.index_map
    points = _dof_points(V)
    distance = np.linalg.norm(points - 0.5 * (np.asarray(box.lo) + np.asarray(box.hi)), axis=1)
    distance[np.any(_on_plus(points.T, box), axis=0)] = np.inf
    if len(points):
        at_vertex = cKDTree(V.mesh.geometry.x).query(points, distance_upper_bound=box.tol)[0] < box.tol
        distance[~at_vertex] = np.inf
    mine = (float(distance.min()), comm.rank) if len(distance) else (np.inf, comm.rank)
    owner = comm.allreduce(mine, op=MPI.MIN)[1]
    chosen = comm.bcast(imap.local_range[0] + int(np.argmin(distance)) if comm.rank == owner else None, root=owner)
    every = imap.local_to_global(np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32))
    blocks = np.flatnonzero(every == chosen).astype(np.int32)
    bs = V.dofmap.index_map_bs
    zero = np.zeros(bs, dtype=dolfinx.default_scalar_type) if bs > 1 else dolfinx.default_scalar_type(0)
    return dolfinx.fem.dirichletbc(zero, blocks, V)
