"""A solution read out of a ContactProblem's unknowns and gaps (DESIGN.md 6, 8): each yarn's
displacement, its gap and contact fields, the penetration left, and a mould's pressure. Every
function is collective.
"""

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
from textile_fenicsx.plate.mesh.midsurface import MidSurfaces
from textile_fenicsx.plate.solver.pairs import NONE, ContactPair, Nodes
from textile_fenicsx.plate.solver.plates import Translation

__all__ = ["displacements", "fields", "penetration", "platen_pressure"]


def penetration(comm: MPI.Comm, pairs: list[ContactPair], g: list[np.ndarray]) -> tuple[float, float]:
    """The largest -g at the overlap dofs [mm] (0 when none penetrates) and the volume the gap
    field says, the integral of max(0, -g) over the overlaps [mm^3]."""
    worst, volume = 0.0, 0.0
    for p, gp in zip(pairs, g):
        if len(gp):
            worst = max(worst, float(np.max(-gp)))
        p.fill(gp)
        volume += dolfinx.fem.assemble_scalar(p.forms.penetration)
    return comm.allreduce(worst, op=MPI.MAX), comm.allreduce(volume, op=MPI.SUM)


def displacements(ms: MidSurfaces, R: list, translation: Translation, x: PETSc.Vec) -> list[dolfinx.fem.Function]:
    """Per yarn w = R_i x [mm], after the common translation is set to zero area-weighted mean
    (x is shifted in place). R: per yarn its maps R_i, one per surface of unknowns."""
    translation.remove(x)
    w = []
    for y, maps in zip(ms.yarns, R):
        w.append(dolfinx.fem.Function(y.V, name="w"))
        maps[0].mult(x, w[-1].x.petsc_vec)
        if len(maps) == 2:  # the mid-surface: the mean of the bottom's and the top's
            top = w[-1].x.petsc_vec.duplicate()
            maps[1].mult(x, top)
            w[-1].x.petsc_vec.axpy(1.0, top)
            w[-1].x.petsc_vec.scale(0.5)
            top.destroy()
        w[-1].x.scatter_forward()
    return w


def platen_pressure(comm: MPI.Comm, ms: MidSurfaces, nodes: Nodes, forces: np.ndarray) -> float:
    """A mould's pressure on the fabric [N/mm^2 = MPa]: the bottom platen's force (the sum of its
    nodes' forces [N]) over the cell's area."""
    bottom = (nodes.pair == NONE) & (nodes.rows_l == NONE)
    total = comm.allreduce(float(np.sum(forces[bottom])), op=MPI.SUM)
    cell = ms.projected.cell
    assert cell is not None  # projected meshes are made with their cell
    return total / cell.area


def fields(ms: MidSurfaces, pairs: list[ContactPair], g: list[np.ndarray],
           active: list[np.ndarray]) -> tuple[list, list]:
    """Per yarn, its gap to the yarn below [mm] (0 where none is) and where contact is active (1),
    for output. The owner of a dof may hold no cell of its pair: the values go to the owners
    (the largest, from -inf where a rank has none), then to the ghosts."""
    gaps, states = [], []
    for y in ms.yarns:
        gaps.append(dolfinx.fem.Function(y.V, name="gap_below"))
        gaps[-1].x.array[:] = -np.inf
        states.append(dolfinx.fem.Function(y.V, name="contact"))
    for p, gp, a in zip(pairs, g, active):
        gaps[p.upper].x.array[p.dofs] = gp
        states[p.upper].x.array[p.dofs] = a.astype(float)
    for f in gaps + states:
        f.x.petsc_vec.ghostUpdate(addv=PETSc.InsertMode.MAX_VALUES, mode=PETSc.ScatterMode.REVERSE)
        f.x.scatter_forward()
    for f in gaps:
        f.x.array[np.isneginf(f.x.array)] = 0.0
    return gaps, states
