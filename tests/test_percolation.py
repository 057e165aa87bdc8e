"""The pores' pockets and percolation (flow/percolation.py), on graphs whose answer is known by hand
and on cells whose pores are a channel along x and a closed pocket."""

import numpy as np
import pytest
from mpi4py import MPI

import dolfinx
from textile_fenicsx.flow.effective import PermeabilityOptions, permeability
from textile_fenicsx.flow.percolation import pockets
from textile_fenicsx.volume.files import VolumeFields


def test_a_ring_along_x_percolates_along_x_only():
    # nodes 0-1-2-3 in a row, node 4 on the + face is node 0's image one period along x
    held, percolates = pockets(np.array([[0, 1], [1, 2], [2, 3], [3, 4]]), np.array([4]), np.array([0]),
                               np.array([[1, 0, 0]]))
    assert held.tolist() == [0] and percolates.tolist() == [True, False, False]


def test_separate_pockets_each_hold_one_node_and_do_not_percolate():
    # two pockets {0, 1} and {5, 7}; node 9 on a + corner is 5's image along y and z, in the second
    held, percolates = pockets(np.array([[0, 1], [5, 7], [7, 9]]), np.array([9]), np.array([5]),
                               np.array([[0, 1, 1]]))
    assert held.tolist() == [0, 5] and percolates.tolist() == [False, True, True]
    # a + face node joined to its own pocket's node without going round: an edge across the cell
    # that closes no cycle (the pocket touches both faces but no path crosses the cell)
    held, percolates = pockets(np.array([[0, 1]]), np.array([2]), np.array([1]), np.array([[1, 0, 0]]))
    assert held.tolist() == [0] and not np.any(percolates)


def channel_fields(pocket: bool, comm=MPI.COMM_WORLD) -> VolumeFields:
    """A 6 x 6 x 6 hexahedral unit box, solid (a yarn, phase 1) but for a straight channel of one
    cell row along x at y, z in [1/3, 1/2] and, if asked, a closed pocket of one cell at (5/6, 5/6,
    5/6)'s corner cell away from it."""
    msh = dolfinx.mesh.create_unit_cube(comm, 6, 6, 6, dolfinx.mesh.CellType.hexahedron)
    imap = msh.topology.index_map(3)
    cells = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
    x = dolfinx.mesh.compute_midpoints(msh, 3, cells)
    pore = (np.abs(x[:, 1] - 5 / 12) < 0.05) & (np.abs(x[:, 2] - 5 / 12) < 0.05)
    if pocket:
        pore |= np.all(np.abs(x - 0.75) < 0.05, axis=1)
    owned = np.arange(imap.size_local, dtype=np.int32)
    tags = dolfinx.mesh.meshtags(msh, 3, owned, (~pore[owned]).astype(np.int32))
    V3 = dolfinx.fem.functionspace(msh, ("DG", 0, (3,)))
    W = dolfinx.fem.functionspace(msh, ("DG", 0))
    d, f = dolfinx.fem.Function(V3), dolfinx.fem.Function(W)
    d.x.array.reshape(-1, 3)[V3.dofmap.list[cells, 0]] = np.where(pore[:, None], 0.0, [1.0, 0.0, 0.0])
    f.x.array[W.dofmap.list[cells, 0]] = np.where(pore, 0.0, 0.5)
    return VolumeFields(msh, tags, d, f)


@pytest.mark.mpi
@pytest.mark.parametrize("solver", ["direct", "iterative"])
def test_a_channel_with_a_closed_pocket(solver):
    """Impermeable yarns around a channel along x: the fluid crosses the cell along x only, so K is
    0 but for Kxx (and says so); a closed pocket of fluid elsewhere has a pressure of its own (held
    separately, else the system is singular) and carries no flow: K is the same with it."""
    options = PermeabilityOptions(yarns="impermeable", solver=solver)
    alone = permeability(channel_fields(pocket=False), options)
    with_pocket = permeability(channel_fields(pocket=True), options)
    for result in (alone, with_pocket):
        assert result.options["percolates"] == {"x": True, "y": False, "z": False}
        assert result.K[0, 0] > 0 and np.count_nonzero(result.K) == 1
        assert result.checks["positive_definite"]  # on the axes the pores percolate along: x
    # the same to the solve's accuracy: round-off for MUMPS; FGMRES stops at a residual 1e-6 of the
    # load's (problem.ITERATIVE), which moved K by 3e-6 here
    assert with_pocket.K[0, 0] == pytest.approx(alone.K[0, 0], rel=1e-9 if solver == "direct" else 1e-5)
    assert with_pocket.porosity == pytest.approx(alone.porosity + 1 / 216, rel=1e-12)
