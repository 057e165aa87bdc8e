"""Files appear whole or not at all: write to a temporary name beside the target, then rename."""

import contextlib
import os
import tempfile
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside `path`; on success it replaces `path`, on error it is removed."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def staged_folder(out, comm=None):
    """Yield a temporary folder beside `out`; when the block succeeds its files move into `out`
    (created if needed), otherwise nothing appears. Collective when given a communicator: rank 0
    owns the folder, every rank gets its path."""
    import shutil

    out = Path(out)
    rank = 0 if comm is None else comm.rank
    tmp = None
    if rank == 0:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent)
    if comm is not None:
        tmp = comm.bcast(tmp, root=0)
    tmp = Path(tmp)
    ok = False
    try:
        yield tmp
        ok = True
    finally:
        if comm is not None:
            ok = comm.allreduce(ok, op=__import__("mpi4py").MPI.LAND)
        if rank == 0:
            if ok:
                out.mkdir(parents=True, exist_ok=True)
                for f in sorted(tmp.iterdir()):
                    os.replace(f, out / f.name)
            shutil.rmtree(tmp, ignore_errors=True)
