"""Under mpirun, an exception on one rank ends every rank.

An uncaught exception ends its own process only; the other ranks then wait forever in the next
collective call (a demo whose rank 0 cannot write its output, a benchmark case that fails on one
rank). When textile_fenicsx is imported in a job of more than one rank, `install_excepthook`
replaces sys.excepthook: the traceback is printed with the rank in front of every line, then
MPI_Abort ends the whole job with exit code 1. Exceptions that a program catches (pytest catches
every test's) never reach the hook, so pytest under mpirun reports failures as usual; SystemExit
does not reach it either.

`wait_asleep(comm)` is a barrier at which the waiting ranks sleep: where rank 0 alone works on
several threads (gmsh's tet mesh), ranks spinning in MPI would take its cores.
"""

import os
import sys
import time
import traceback


def mpi_world_size() -> int:
    """The number of ranks of the MPI job this process belongs to, from the launcher's environment
    (OpenMPI, MPICH/Hydra, PMIx), without initialising MPI; 1 when not under mpirun."""
    for name in ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE", "MPI_LOCALNRANKS"):
        value = os.environ.get(name)
        if value:
            try:
                return int(value)
            except ValueError:
                pass
    return 1


def wait_asleep(comm, poll: float = 0.05) -> None:
    """Return on every rank of comm once all have called it; a rank waiting polls every `poll`
    seconds and sleeps in between. (OpenMPI's waits spin; with yield_when_idle they call
    sched_yield, which Linux honours loosely: a rank waiting that way still competes with rank 0's
    threads for the cores.)"""
    request = comm.Ibarrier()
    while not request.Test():
        time.sleep(poll)


def _abort_on_uncaught(kind, value, tb) -> None:
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    lines = "".join(traceback.format_exception(kind, value, tb)).splitlines()
    prefix = f"[rank {comm.rank}] "
    text = "".join(f"{prefix}{line}\n" for line in lines)
    text += (f"{prefix}textile_fenicsx: uncaught {kind.__name__} on rank {comm.rank} of {comm.size}: "
             "ending every rank (MPI_Abort)\n")
    try:
        sys.stderr.write(text)
        sys.stderr.flush()
    finally:
        comm.Abort(1)


def install_excepthook() -> bool:
    """Make an uncaught exception on any rank end every rank (above); only when this process is
    one of several MPI ranks and the hook is still Python's own. Returns whether it was installed."""
    if mpi_world_size() <= 1 or sys.excepthook is not sys.__excepthook__:
        return False
    sys.excepthook = _abort_on_uncaught
    return True
