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


def _remove_stale(out: Path) -> None:
    """Remove temporary folders of earlier runs into `out` whose process is gone (a run killed
    mid-write, or ended by MPI_Abort from another rank, cannot clean up after itself)."""
    import shutil

    for old in out.parent.glob(f".{out.name}.partial-*"):
        try:
            pid = int(old.name.split("partial-")[1].split("-")[0])
            os.kill(pid, 0)  # still running: leave it
        except ProcessLookupError:
            shutil.rmtree(old, ignore_errors=True)
        except (ValueError, IndexError, PermissionError):
            pass


@contextlib.contextmanager
def staged_folder(out, comm=None, remove: tuple = ()):
    """Yield a temporary folder beside `out`; when the block succeeds on every rank its files move
    into `out` (created if needed; same-named files and folders are replaced, others kept),
    otherwise nothing appears. Collective when given a communicator: rank 0 owns the folder,
    every rank gets its path. `remove`: names in `out` to delete when the new files land (left
    over from an earlier run of another kind). On an error nothing is communicated (the failing rank may be alone):
    rank 0 removes the folder if it failed itself; else the next run into `out` removes it."""
    import shutil

    out = Path(out)
    rank = 0 if comm is None else comm.rank
    tmp = None
    if rank == 0:
        out.parent.mkdir(parents=True, exist_ok=True)
        _remove_stale(out)
        tmp = tempfile.mkdtemp(prefix=f".{out.name}.partial-{os.getpid()}-", dir=out.parent)
    if comm is not None:
        tmp = comm.bcast(tmp, root=0)
    tmp = Path(tmp)
    try:
        yield tmp
    except BaseException:
        if rank == 0:
            shutil.rmtree(tmp, ignore_errors=True)
        raise
    if comm is not None:
        comm.barrier()  # every rank has written its part
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        for name in remove:
            old = out / name
            if old.is_dir() and not old.is_symlink():
                shutil.rmtree(old)
            else:
                old.unlink(missing_ok=True)
        for f in sorted(tmp.iterdir()):
            target = out / f.name
            if target.is_dir() and not target.is_symlink():  # a folder of an earlier run
                shutil.rmtree(target)
            os.replace(f, target)
        shutil.rmtree(tmp, ignore_errors=True)
