"""Files appear whole or not at all: write to a temporary name beside the target, then rename.

An output folder is written by one run at a time (`output_lock`: a lock file beside it), is checked
before the work that fills it (`claim_output`: writable, not the input's own folder), and is
assembled under a temporary name (`staged_folder`). Every error of a write names the file.
"""

import contextlib
import errno
import fcntl
import os
import tempfile
from pathlib import Path

from textile_fenicsx.common.errors import OutputError, TextileError


def _full(path: Path) -> bool:
    """Is the file system of `path` (or of its nearest existing parent) full?"""
    for folder in (path, *path.parents):
        try:
            st = os.statvfs(folder)
        except OSError:
            continue
        return st.f_bavail * st.f_frsize < 64 * 1024
    return False


@contextlib.contextmanager
def naming(path):
    """Errors raised in the block name `path`: an OSError without a file name (a full disk's ENOSPC
    is raised by a write or a close, not by the open that knows the name) gets it; one without an
    error number (numpy's short writes) is ENOSPC when the disk is full."""
    try:
        yield
    except OSError as e:
        if e.filename is not None:
            raise
        number, reason = e.errno, e.strerror or str(e)
        if not number and _full(Path(path)):
            number, reason = errno.ENOSPC, f"{os.strerror(errno.ENOSPC)} ({e})"
        raise OSError(number or errno.EIO, reason, str(path)) from e


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside `path`; on success it replaces `path`, on error it is removed.
    An OSError in the block names `path` (not the temporary name)."""
    path = Path(path)
    with naming(path):
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        with naming(path):
            yield Path(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _collective(error: Exception) -> Exception:
    """The error, marked as raised on every rank at the same place (cli._fail reports it once)."""
    setattr(error, "collective", True)  # noqa: B010 (an attribute OSError does not declare)
    return error


def _remove_stale(out: Path, every: bool = False) -> None:
    """Remove temporary folders of earlier runs into `out` whose process is gone (a run killed
    mid-write, or ended by MPI_Abort from another rank, cannot clean up after itself); `every`:
    all of them (the caller holds the folder's lock, so no other run is writing them)."""
    import shutil

    for old in out.parent.glob(f".{out.name}.partial-*"):
        if every:
            shutil.rmtree(old, ignore_errors=True)
            continue
        try:
            pid = int(old.name.split("partial-")[1].split("-")[0])
            os.kill(pid, 0)  # still running: leave it
        except ProcessLookupError:
            shutil.rmtree(old, ignore_errors=True)
        except (ValueError, IndexError, PermissionError):
            pass


def lock_path(out) -> Path:
    """The lock file of output folder `out`: `.NAME.lock` beside it."""
    out = Path(out)
    return out.parent / f".{out.name}.lock"


_held: dict = {}  # lock file -> [descriptor, how many holders in this process]


def _acquire(out: Path) -> None:
    path = lock_path(out)
    key = str(path.resolve())
    if key in _held:
        _held[key][1] += 1
        return
    while True:
        with naming(path):
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.read(fd, 64).decode(errors="replace").strip()
            finally:
                os.close(fd)
            raise OutputError(f"another run is writing {out} (process {holder or '?'} holds {path}); "
                              "wait for it to end or choose another --out") from None
        # the holder before us may have removed the file between our open and our lock: retry
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()}\n".encode())
    _held[key] = [fd, 1]


def _release(out: Path) -> None:
    path = lock_path(out)
    key = str(path.resolve())
    entry = _held.get(key)
    if entry is None:
        return
    entry[1] -= 1
    if entry[1] == 0:
        del _held[key]
        Path(path).unlink(missing_ok=True)  # while still locked: no other run holds this file
        os.close(entry[0])


def abandon_outputs() -> None:
    """What a run ended at once leaves behind, removed (interrupts.py: a signal while the run is
    held in native code): this process's temporary folders beside each output it holds, and the
    output's lock file."""
    import shutil

    for key in list(_held):
        lock = Path(key)
        name = lock.name[1:-len(".lock")]
        for tmp in lock.parent.glob(f".{name}.partial-{os.getpid()}-*"):
            shutil.rmtree(tmp, ignore_errors=True)
        lock.unlink(missing_ok=True)


@contextlib.contextmanager
def output_lock(out, comm=None):
    """Hold the lock of output folder `out` for the block (rank 0 holds it; collective with a
    communicator: every rank raises if it is taken). Re-entrant within a process. A second run
    into `out` meanwhile fails at once (OutputError) and writes nothing; the lock file is removed
    when the block ends (a run killed hard leaves it unlocked, and the next run takes it)."""
    out = Path(out)
    rank = 0 if comm is None else comm.rank
    error = None
    if rank == 0:
        try:
            with naming(out.parent):
                out.parent.mkdir(parents=True, exist_ok=True)
            _acquire(out)
        except (OSError, OutputError) as e:
            error = e
    if comm is not None:
        error = comm.bcast(error, root=0)
    if error is not None:
        raise _collective(error)  # every rank raises it here
    try:
        yield
    finally:
        if rank == 0:
            _release(out)


def _inside(path: Path, folder: Path) -> Path | None:
    """path relative to folder when it lies inside it, else None."""
    try:
        return path.relative_to(folder)
    except ValueError:
        return None


def check_output(out, inputs=(), names=(), force: bool = False) -> None:
    """Refuse, before any work, an output folder that cannot take the run's files (this rank's
    view; raises TextileError for a bad choice, OSError naming the path for an unwritable one):
    `out` must be a folder or not exist, not be the folder of an input (unless `force`), and
    never hold an input under a name the run writes or removes (`names`: the run's top-level
    names in `out`). Writes nothing."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise TextileError(f"--out {out} is an existing file, not a folder")
    where = out.resolve()
    for given in inputs:
        given = Path(given)
        if not given.exists():
            continue
        src = given.resolve()
        inner = _inside(src, where)
        if inner is not None and inner.parts and inner.parts[0] in set(names):
            raise TextileError(f"--out {out} would replace or remove the input {given} (the run writes "
                               f"{inner.parts[0]} there); choose another --out")
        if src.parent == where and not force:
            raise TextileError(f"--out {out} is the folder of the input {given}; choose another folder, or give "
                               "--force to write the results beside the input (it is never replaced)")


def _check_writable(out: Path) -> None:
    """Create `out`'s parent folders if missing; raise an OSError naming the folder if files cannot
    be created in it (or in `out`, when it exists)."""
    with naming(out.parent):
        out.parent.mkdir(parents=True, exist_ok=True)
    for folder in ([out] if out.is_dir() else []) + [out.parent]:
        with naming(folder):
            with tempfile.TemporaryFile(dir=folder, prefix=f".{out.name}.check-"):
                pass


@contextlib.contextmanager
def claim_output(out, inputs=(), names=(), force: bool = False, comm=None):
    """Before the work that fills output folder `out`: check it (check_output), create its parent,
    take its lock for the block (a concurrent run into `out` fails here, having written nothing),
    check that it is writable and remove temporary folders that earlier runs into it left behind
    (on rank 0; collective with a communicator: an error there is raised on every rank)."""
    out = Path(out)
    rank = 0 if comm is None else comm.rank

    def collective(step):
        error = None
        if rank == 0:
            try:
                step()
            except (OSError, TextileError) as e:
                error = e
        if comm is not None:
            error = comm.bcast(error, root=0)
        if error is not None:
            raise _collective(error)  # every rank raises it here

    def parent():
        check_output(out, inputs, names, force)
        with naming(out.parent):
            out.parent.mkdir(parents=True, exist_ok=True)

    collective(parent)
    with output_lock(out, comm):
        def check_and_clean():
            _check_writable(out)
            _remove_stale(out, every=True)

        collective(check_and_clean)
        yield


@contextlib.contextmanager
def staged_folder(out, comm=None, remove: tuple | list = ()):
    """Yield a temporary folder beside `out`; when the block succeeds on every rank its files move
    into `out` (created if needed; same-named files and folders are replaced, others kept),
    otherwise nothing appears. Collective when given a communicator: rank 0 owns the folder,
    every rank gets its path. `remove`: names in `out` to delete when the new files land (left
    over from an earlier run of another kind). Holds `out`'s lock (output_lock) meanwhile. An
    OSError in the block names the file by its place in `out`. On an error in the block nothing
    is communicated (the failing rank may be alone): rank 0 removes the folder if it failed
    itself; else the next run into `out` removes it (and under mpirun the failing rank ends
    every rank: textile_fenicsx's excepthook)."""
    import shutil

    out = Path(out)
    rank = 0 if comm is None else comm.rank
    with output_lock(out, comm):
        tmp, error = None, None
        if rank == 0:
            try:
                if out.exists() and not out.is_dir():
                    raise OSError(errno.ENOTDIR, "an existing file, not a folder", str(out))
                with naming(out.parent):
                    out.parent.mkdir(parents=True, exist_ok=True)
                    _remove_stale(out)
                    tmp = tempfile.mkdtemp(prefix=f".{out.name}.partial-{os.getpid()}-", dir=out.parent)
            except OSError as e:
                error = e
        if comm is not None:
            tmp, error = comm.bcast((tmp, error), root=0)
        if error is not None:  # every rank learns it: none waits for the others
            raise _collective(error)
        assert tmp is not None
        folder = Path(tmp)
        try:
            try:
                yield folder
            except OSError as e:  # name the file as it would have been in `out`, not in the temporary folder
                inner = _inside(Path(e.filename), folder) if isinstance(e.filename, str) else None
                if inner is not None:
                    raise OSError(e.errno, e.strerror, str(out / inner)) from e
                raise
        except BaseException:
            if rank == 0:
                shutil.rmtree(folder, ignore_errors=True)
            raise
        if comm is not None:
            comm.barrier()  # every rank has written its part
        if rank == 0:
            with naming(out):
                out.mkdir(parents=True, exist_ok=True)
                for name in remove:
                    old = out / name
                    if old.is_dir() and not old.is_symlink():
                        shutil.rmtree(old)
                    else:
                        old.unlink(missing_ok=True)
                for f in sorted(folder.iterdir()):
                    target = out / f.name
                    if target.is_dir() and not target.is_symlink():  # a folder of an earlier run
                        shutil.rmtree(target)
                    os.replace(f, target)
            shutil.rmtree(folder, ignore_errors=True)
