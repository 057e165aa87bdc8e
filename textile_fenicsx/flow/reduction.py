"""The flow problem's periodicity and held dofs, by PETSc alone (problem.py's docstring says why).

R maps the unknowns kept to every dof of the mixed space W: R[i, i] = 1 for a dof kept, R[s, m] = 1
for a slave s on a + face and its master m at its image, matched by location and component as
homogenisation/periodic.py matches them (every + coordinate wrapped at once, one master each,
coefficient 1). A form's matrix A is reduced to R^T A R, whose slave rows and columns are then the
identity's, as are those of the dofs held at 0: the pressure's constant (one dof; with solid yarns,
one in each pocket of the pores, percolation.py), and where the yarns are solid, the velocity of
their cells (no-slip on their surfaces) and the pressure dofs that touch no pore.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc
from scipy.spatial import cKDTree

import dolfinx
import dolfinx.fem.petsc
from textile_fenicsx.common.errors import GeometryError
from textile_fenicsx.common.petsc import petsc_options
from textile_fenicsx.flow.percolation import pockets
from textile_fenicsx.homogenisation.periodic import Box, check_node_periodicity

__all__ = ["Reduction", "images", "periodic_reduction", "reduced", "touching"]

# MatPtAP's algorithm for R^T A R (PETSc's option -matptap_via). R has one entry a row, and PETSc's
# defaults took most of the assembly: on the satin's 0.3 mm voxels (124 k Taylor-Hood unknowns, 23 M
# entries) 21.7 s serially ("sorted"), 10.4 s on 2 ranks ("scalable"); "rap" took 1.0-1.4 s
# serially, "allatonce" 2.0 s on 2 ranks ("nonscalable" 4.7), the same matrix (2026-12-07)
PTAP_SERIAL, PTAP_PARALLEL = "rap", "allatonce"


@dataclass
class Reduction:
    """R (module docstring); held: the owned rows held at 0 (global indices); fields: the owned
    velocity and pressure rows (global indices); percolates: whether the pores let the fluid
    across the cell along x, y, z; slaves: how many dofs are slaves (every rank's)."""

    R: PETSc.Mat
    held: np.ndarray
    fields: tuple[np.ndarray, np.ndarray]
    percolates: np.ndarray
    slaves: int


def _labelled_dofs(W: dolfinx.fem.FunctionSpace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every local dof of the mixed space W (owned, then ghosts): its W index, location and label
    (0, 1, 2: the velocity's components; 3: the pressure). Each sub-space's cell dofs are in the
    order of a scalar Lagrange space of its degree, whose dof coordinates DOLFINx tabulates
    (collapsing the sub-spaces instead took 6.5 s on the satin's 0.3 mm Q2 voxels, this 0.03 s)."""
    mesh = W.mesh
    n = W.dofmap.index_map.size_local + W.dofmap.index_map.num_ghosts
    points, labels = np.zeros((n, 3)), np.full(n, -1, np.int32)
    for field, parts in ((0, [W.sub(0).sub(c) for c in range(3)]), (1, [W.sub(1)])):
        scalar = dolfinx.fem.functionspace(mesh, ("Lagrange", W.sub(field).ufl_element().degree))
        x, cells = scalar.tabulate_dof_coordinates(), np.asarray(scalar.dofmap.list)
        for c, part in enumerate(parts):
            dofs = np.asarray(part.dofmap.list)
            points[dofs] = x[cells]
            labels[dofs] = 3 * field + c
    return np.arange(n, dtype=np.int32), points, labels


def periodic_reduction(W: dolfinx.fem.FunctionSpace, box: Box, solid: np.ndarray | None) -> Reduction:
    """The reduction of the mixed space W on the periodic box (module docstring); solid: a boolean
    per local cell, True where the yarns are impermeable, or None (collective)."""
    comm = W.mesh.comm
    imap = W.dofmap.index_map
    owned = imap.size_local
    local, points, labels = _labelled_dofs(W)
    glob = imap.local_to_global(local).astype(np.int64)
    slaves, masters, plus = images(comm, points, labels, glob, owned, box)
    columns = glob[:owned].copy()
    columns[slaves] = masters
    n_global = imap.size_global
    R = PETSc.Mat().createAIJ(((owned, n_global), (owned, n_global)),
                              csr=(np.arange(owned + 1, dtype=PETSc.IntType), columns.astype(PETSc.IntType),
                                   np.ones(owned)), comm=comm)
    held = np.zeros(owned, bool)
    held[slaves] = True
    pressure = labels[:owned] == 3
    live = np.ones(owned, bool)  # pressure dofs that touch a pore
    if solid is not None:
        in_solid, in_fluid = touching(W, solid, glob, slaves, masters)
        held |= in_solid & (labels[:owned] < 3)  # no-slip: the velocity of the solid's cells
        live = in_fluid
        held |= pressure & ~in_fluid
        ps = labels[slaves] == 3
        constants, percolates = _pockets(W, solid, glob, glob[slaves[ps]], masters[ps], plus[slaves[ps]])
        held |= np.isin(glob[:owned], constants)  # the pressure's constant in each pocket
    else:
        candidates = glob[:owned][pressure & live & ~held]
        first = comm.allreduce(int(candidates.min()) if len(candidates) else np.iinfo(np.int64).max, op=MPI.MIN)
        held |= glob[:owned] == first  # the pressure's constant
        percolates = np.ones(3, bool)  # the porous yarns let the fluid through everywhere
    fields = (glob[:owned][labels[:owned] < 3], glob[:owned][labels[:owned] == 3])
    return Reduction(R, glob[:owned][held].astype(PETSc.IntType), fields, percolates,
                     comm.allreduce(len(slaves), op=MPI.SUM))


def images(comm: MPI.Comm, points: np.ndarray, labels: np.ndarray, glob: np.ndarray, owned: int,
           box: Box) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The slaves among the owned dofs (local indices: those on a + face), the global index of
    each one's master (the dof of the same label at its image, every + coordinate wrapped at once)
    and which + faces each owned dof is on (owned, 3). points, labels, glob: every local dof's
    location, kind and global index, the owned first (collective)."""
    lo, hi = np.asarray(box.lo), np.asarray(box.hi)
    on_face = np.any((np.abs(points - lo) < box.tol) | (np.abs(points - hi) < box.tol), axis=1)
    mine = np.flatnonzero(on_face[:owned])
    face = [np.concatenate(x) for x in zip(*comm.allgather((points[mine], labels[mine], glob[mine])))]
    plus = np.abs(points[:owned] - hi) < box.tol
    slaves = np.flatnonzero(np.any(plus, axis=1))
    masters = np.empty(len(slaves), np.int64)
    wrapped = points[slaves] - plus[slaves] * np.asarray(box.size)
    for label in np.unique(face[1]):
        here = face[1] == label
        check_node_periodicity(face[0][here], box, "the flow problem's dof locations")
        mine_l = labels[slaves] == label
        if not np.any(mine_l):
            continue
        distance, nearest = cKDTree(face[0][here]).query(wrapped[mine_l], distance_upper_bound=box.tol)
        if not np.all(np.isfinite(distance)):
            raise GeometryError("flow problem: a + face dof has no dof of its kind at its image")
        masters[mine_l] = face[2][here][nearest]
    return slaves, masters, plus


def _pockets(W: dolfinx.fem.FunctionSpace, solid: np.ndarray, glob: np.ndarray, slaves: np.ndarray,
             masters: np.ndarray, wraps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pressure dof held in each pocket of the pores and the axes they percolate along
    (percolation.pockets, on rank 0 from every rank's pore cells and pressure slaves; collective)."""
    owned_cells = W.mesh.topology.index_map(3).size_local
    pore = np.flatnonzero(~solid[:owned_cells])
    cells = glob[np.asarray(W.sub(1).dofmap.list)[pore]]
    gathered = W.mesh.comm.gather((cells, slaves, masters, wraps.astype(np.int64)), root=0)
    result: Exception | tuple[np.ndarray, np.ndarray] | None = None
    if W.mesh.comm.rank == 0:
        c, s, m, w = (np.concatenate(x) for x in zip(*gathered))
        if len(c) == 0:
            result = GeometryError("flow problem: no pore to hold the fluid (every cell is solid)")
        else:
            result = pockets(c, s, m, w)
    result = W.mesh.comm.bcast(result, root=0)
    if isinstance(result, Exception):
        raise result
    return result


def _diagonal(A: PETSc.Mat, rows: np.ndarray) -> PETSc.Mat:
    """A matrix of A's layout with a 1 on the diagonal at the (owned, global) rows given and
    nothing elsewhere."""
    first, end = A.getOwnershipRange()
    n, N = end - first, A.getSize()[0]
    counts = np.zeros(n + 1, dtype=PETSc.IntType)
    counts[rows - first + 1] = 1
    return PETSc.Mat().createAIJ(((n, N), (n, N)), csr=(np.cumsum(counts).astype(PETSc.IntType),
                                                        np.sort(rows).astype(PETSc.IntType),
                                                        np.ones(len(rows))), comm=A.comm)


def touching(W: dolfinx.fem.FunctionSpace, solid: np.ndarray, glob: np.ndarray, slaves: np.ndarray,
              masters: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whether each owned dof, or a periodic image of it, belongs to a solid cell and to a pore
    cell (collective: the cells of other ranks and across the box's faces count). W: the mixed
    space, or a blocked space with glob, slaves and masters of its blocks (nodes)."""
    imap = W.dofmap.index_map
    owned = imap.size_local
    cells = np.asarray(W.dofmap.list)
    flags = []
    for chosen in (solid, ~solid):
        vec = dolfinx.la.vector(imap, 1)
        vec.array[np.unique(cells[chosen])] = 1.0
        vec.scatter_reverse(dolfinx.la.InsertMode.add)
        here = vec.array[:owned] > 0
        seen = np.concatenate(W.mesh.comm.allgather(masters[here[slaves]]))  # a slave's own cells
        flags.append(here | np.isin(glob[:owned], seen))
    return flags[0], flags[1]


def reduced(form: dolfinx.fem.Form, reduction: Reduction) -> PETSc.Mat:
    """R^T A R of the form's matrix A, its held rows and columns the identity's (collective)."""
    A = dolfinx.fem.petsc.assemble_matrix(form)
    A.assemble()
    try:
        with petsc_options("", {"matptap_via": PTAP_SERIAL if A.comm.size == 1 else PTAP_PARALLEL}):
            B = A.PtAP(reduction.R)
    finally:
        A.destroy()
    # the held rows of R^T A R are empty (a slave's) or not: give each a diagonal entry (merged in
    # by axpy with a diagonal of the held rows; MPIAIJ's zeroRowsColumns needs the entry, and
    # inserting them one at a time into the assembled matrix took 3 ms each), then make them
    # the identity's, with -1 for the pressure's: the sign of the Schur complement -B A^-1 B^T, so
    # that its preconditioner (selfp: the pressure rows of the held dofs, minus B diag(A)^-1 B^T) is
    # definite: with +1, BoomerAMG stalled on it where solid yarns hold thousands of pressure dofs
    # (the satin's 0.3 mm voxels: the residual stuck at 0.04 of the load's, then diverged)
    diagonal = _diagonal(B, reduction.held)
    B.axpy(1.0, diagonal, PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
    diagonal.destroy()
    pressure = np.isin(reduction.held, reduction.fields[1])
    B.zeroRowsColumns(reduction.held[~pressure], 1.0)
    B.zeroRowsColumns(reduction.held[pressure], -1.0)
    return B
