"""Shared fixtures and markers.

Markers (pyproject.toml): `serial` tests run in the serial pass only; `mpi` tests run in the serial
pass and again under `mpirun -n 2` (make test). Every test must pass on any number of ranks it is
run on; an `mpi` test is written collectively (all ranks call the same things).
"""

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

REPO = Path(__file__).resolve().parent.parent
REFERENCE = Path(os.environ.get("TEXTILE_FENICSX_REFERENCE", REPO / "reference"))


@pytest.hookimpl(trylast=True)
def pytest_configure(config):
    # Under mpirun, only rank 0 reports; the others' failures still fail the run (exit code).
    if MPI.COMM_WORLD.size > 1 and MPI.COMM_WORLD.rank != 0:
        reporter = config.pluginmanager.get_plugin("terminalreporter")
        if reporter is not None:
            config.pluginmanager.unregister(reporter)


@pytest.fixture
def comm():
    return MPI.COMM_WORLD


@pytest.fixture
def mpi_tmp_path(request):
    """A temporary folder shared by all ranks: rank 0 creates and removes it, the others are told."""
    comm = MPI.COMM_WORLD
    path = None
    if comm.rank == 0:
        path = tempfile.mkdtemp(prefix=f"tfx-{request.node.name[:40]}-")
    path = Path(comm.bcast(path, root=0))
    yield path
    comm.barrier()
    if comm.rank == 0:
        shutil.rmtree(path, ignore_errors=True)


@pytest.fixture(scope="session")
def reference_dir():
    if not REFERENCE.is_dir():
        pytest.fail(f"reference data not found at {REFERENCE} (set TEXTILE_FENICSX_REFERENCE)")
    return REFERENCE


def gmsh_groups(path) -> dict[str, tuple[int, float]]:
    """Each physical volume group of a .msh file as gmsh itself opens it: name -> (elements, their
    volume [mm^3] by gmsh's own measure). gmsh reads the file into a model of its own, removed after."""
    import gmsh

    initialised = gmsh.isInitialized()
    if not initialised:
        gmsh.initialize(["-noenv"], interruptible=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("read back")
    try:
        gmsh.merge(str(path))
        groups = {}
        for dim, tag in gmsh.model.getPhysicalGroups(3):
            tags = [t for entity in gmsh.model.getEntitiesForPhysicalGroup(dim, tag)
                    for t in np.concatenate(gmsh.model.mesh.getElements(dim, entity)[1] or [[]])]
            volume = float(np.sum(gmsh.model.mesh.getElementQualities(tags, "volume"))) if tags else 0.0
            groups[gmsh.model.getPhysicalName(dim, tag)] = (len(tags), volume)
        return groups
    finally:
        gmsh.model.remove()
        if not initialised:
            gmsh.finalize()
