"""Ctrl-C and SIGTERM that end a run also while it is inside native code (gmsh, MUMPS).

The command line turns SIGINT and SIGTERM into KeyboardInterrupt (cli.py), and the run ends with
exit 130, its message and nothing left behind. Python runs a signal's handler only between byte
codes of its main thread, so a run inside one long native call, gmsh meshing a volume for minutes
or an OpenCASCADE boolean that does not return, did not answer a signal until the call returned,
or ever (`timeout 900` and `kill -TERM` left a stuck gmsh running for over 20 minutes,
until SIGKILL).

`watch` (the command line calls it) adds a watcher: the signal's number is written to a pipe as it
arrives (signal.set_wakeup_fd, which the interpreter does in C, whatever the main thread is doing),
and a daemon thread reads it.
If the handler has not run GRACE seconds later, the main thread is held in native code: the watcher
ends the run itself, as the handler would have, with the same message and exit code, after
`cleanup` (the output's lock and temporary folders: files.abandon_outputs).

`time_limit` bounds a block the same way: a native call that never returns (gmsh 4.13's initial 2D
Delaunay, GFaceInitialMesh, looped for over 20 minutes on the projected regions of TexGen's refined
orthogonal weave moved 0.7 mm in the plane) ends the run with a message that says what to try.
It acts only in a process that `watch`es (the command line): in a user's own Python session it is
not for us to end the process.
"""

import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["GRACE", "handled", "time_limit", "watch"]

# Seconds the handler has to run before the watcher ends the run [s]: a Newton step's factorisation
# returns to Python well within it on the machines we measured (0.1-2 s at the sweep's sizes).
GRACE = 3.0

_handled = threading.Event()


def handled() -> None:
    """Called by the command's own handler: the main thread answered the signal."""
    _handled.set()


def watch(message: Callable[[int], str], cleanup: Callable[[], None], code: int,
          error: Callable[[str], str] = str) -> None:
    """Start the watcher (from the main thread; once per process, a later call only replaces what
    it does): for a SIGINT or SIGTERM not handled within GRACE s, print `message(signum)` to
    stderr, run `cleanup` and end the process with `code`. The signals' own handlers are the
    caller's to install, and they call `handled`. `error`: how the process prints an error's text
    (time_limit's)."""
    _action.update(message=message, cleanup=cleanup, code=code, error=error)
    _handled.clear()  # a new run (the command line's main, called again in one process)
    if "thread" in _action:
        return
    read, write = os.pipe()
    os.set_blocking(write, False)
    signal.set_wakeup_fd(write, warn_on_full_buffer=False)
    _action["thread"] = threading.Thread(target=_watcher, args=(read,), name="interrupt-watcher", daemon=True)
    _action["thread"].start()


_action: dict = {}


def _end(message: str, code: int) -> None:
    """End the process now (from a watcher thread): the message, the run's cleanup, the code."""
    try:
        print(message, file=sys.stderr, flush=True)
        _action["cleanup"]()
    finally:
        os._exit(code)


@contextmanager
def time_limit(seconds: float, message: Callable[[], str], code: int = 1) -> Iterator[None]:
    """End the process with `message()` (stderr), the run's cleanup and `code` if the block has not
    ended after `seconds` [s]; nothing where no `watch` runs (module docstring)."""
    if "thread" not in _action:
        yield
        return
    done = threading.Event()

    def run() -> None:
        if not done.wait(seconds):
            _end(_action["error"](message()), code)

    threading.Thread(target=run, name="time-limit", daemon=True).start()
    try:
        yield
    finally:
        done.set()


def _watcher(read: int) -> None:
    while True:
        signums = [b for b in os.read(read, 16) if b in (signal.SIGINT, signal.SIGTERM)]
        if not signums:
            continue
        if _handled.wait(GRACE):
            continue  # the main thread answered it: the run is ending by its own path
        _end(_action["message"](signums[0]), _action["code"])
