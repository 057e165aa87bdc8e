"""A run's figures, drawn by a process of their own while the run goes on (DESIGN.md 8).

Drawing costs more than writing every other file of a run: on satin4 at seed 0.25, importing
pyvista and matplotlib 0.5 s, an X server 0.2 s, the two 3D views 0.9 s and the cross-sections
0.7 s, a fifth of the command's time, on one core while the other idles. A `Painter` starts
`python -m textile_fenicsx.plot.figures` at once: the child imports its libraries, starts its X
server and draws the input's view (the CLI hands it over first) while the run meshes and solves,
and draws the other figures into a folder of its own while the run measures and writes its other
files; `collect` waits for the figures and moves them into the run's folder. A figure that fails
is an error naming its file, as it was when drawn in process.

The child is not part of an MPI job: the launcher's variables are removed from its environment
and it imports neither mpi4py nor DOLFINx. Jobs are pickled to files in the child's folder and
announced by one line on its stdin (a line never blocks the run, a large pickle in a pipe could);
the child answers one line per figure on its stdout. It ends when its stdin closes (`close`, or
the run's process ending for any reason).
"""

from __future__ import annotations

import os
import pickle
import shutil
import signal
import subprocess
import sys
import tempfile
import traceback
from pathlib import Path

from textile_fenicsx.common.files import naming

__all__ = ["Painter"]

# what each kind of figure calls, in the child: plotting.plot_textile(textile, surfaces, path, title),
# plotting.plot_cross_sections(before, after, path, lines)
KINDS = {"textile": "plot_textile", "cross_sections": "plot_cross_sections"}
# environment variables that would make the child think it is a rank of the run's MPI job
_LAUNCHER_PREFIXES = ("OMPI_", "PMIX_", "PMI_", "PRTE_", "HYDRA_", "MPI_LOCALNRANKS", "MPI_LOCALRANKID")


class Painter:
    """Figures drawn by a child process. Use as a context manager (or call `close`). The child
    leads a process group of its own (with its X server): `close` ends the group, so that a child
    that was killed or crashed (VTK segfaults rather than raise) leaves no X server behind."""

    def __init__(self):
        self.folder = Path(tempfile.mkdtemp(prefix="textile-fenicsx-figures-"))
        env = {k: v for k, v in os.environ.items() if not k.startswith(_LAUNCHER_PREFIXES)}
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)  # the modules the run imports
        try:
            self._log = open(self.folder / "painter.log", "wb")
            self._child = subprocess.Popen([sys.executable, "-m", "textile_fenicsx.plot.figures", str(self.folder)],
                                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._log, env=env,
                                           text=True, bufsize=1, process_group=0)
        except BaseException:
            if hasattr(self, "_log"):
                self._log.close()
            shutil.rmtree(self.folder, ignore_errors=True)
            raise
        assert self._child.stdin is not None and self._child.stdout is not None  # both are pipes
        self._stdin, self._stdout = self._child.stdin, self._child.stdout
        self._pending: dict[str, str] = {}  # the child's file -> the figure's file name
        self.asked: set[str] = set()  # file names of every figure asked for
        self.models: dict[str, object] = {}  # file name -> the model it was last asked for (`draw`)
        # id of a model -> (the model, the yarn surfaces a 3D view of it was given), for the caller's
        # files (outputs.write_run): built once for both
        self.surfaces: dict[int, tuple[object, object]] = {}
        self._count = 0

    def draw(self, figures: list[tuple[str, str, tuple]], model: object = None) -> None:
        """Have the child draw these figures, each (kind (KINDS), file name, arguments); they are
        pickled together, so that objects they share are written once (a corrected model: 0.01 s).
        Figures can be asked for before their folder exists (the CLI asks for the input's view
        before the solve, the corrected model's before its check): `collect` says where they go,
        and a file name asked for again is drawn again, the last drawing kept. `model`: what they
        show, kept in `models` by file name (a caller that may ask again skips what it asked for
        the same model)."""
        jobs = []
        for kind, file_name, args in figures:
            if kind not in KINDS:
                raise ValueError(f"unknown kind of figure {kind!r} (one of {', '.join(KINDS)})")
            self._count += 1
            name = f"{self._count}.png"  # the child's file and answer: never a space in it
            self._pending[name] = file_name
            self.asked.add(file_name)
            self.models[file_name] = model
            if kind == "textile" and args[1] is not None:
                self.surfaces[id(args[0])] = (args[0], args[1])
            jobs.append((name, kind, args))
        if not jobs:
            return
        job = self.folder / f"{self._count}.job"
        with open(job.with_suffix(".part"), "wb") as f:
            pickle.dump(jobs, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(job.with_suffix(".part"), job)
        try:
            self._stdin.write(job.name + "\n")
            self._stdin.flush()
        except (BrokenPipeError, OSError):
            pass  # the child has ended: collect reports why

    def collect(self, folder: Path) -> list[Path]:
        """Wait for every figure asked for and move each into `folder` under its file name; raise
        OSError naming the first that could not be drawn (the child's reason in the message)."""
        done, failed = [], None
        while self._pending:
            line = self._stdout.readline()
            if not line:  # the child ended without answering
                for file_name in self._pending.values():
                    failed = failed or (Path(folder) / file_name, f"the figure process ended ({self._reason()})")
                self._pending.clear()
                break
            status, _, rest = line.rstrip("\n").partition(" ")
            name, _, reason = rest.partition(" ")
            target = Path(folder) / self._pending.pop(name)  # answers come only for figures it was given
            if status == "ok":
                with naming(target):
                    shutil.move(self.folder / name, target)
                done.append(target)
            else:
                failed = failed or (target, reason or "no reason given")
        if failed:
            raise OSError(5, f"the figure could not be drawn: {failed[1]}", str(failed[0]))
        return done

    def _reason(self) -> str:
        self._log.flush()
        text = (self.folder / "painter.log").read_text(errors="replace").strip().splitlines()
        return text[-1] if text else f"exit code {self._child.poll()}"

    def close(self, now: bool = False) -> None:
        """End the child and remove its folder: once it has drawn what it was given (it does
        nothing after the last `collect`), or at once (`now`: the run failed)."""
        if self._child.stdin and not self._child.stdin.closed:
            try:
                self._child.stdin.close()
            except OSError:
                pass
        try:
            self._child.wait(timeout=0 if now else 30)
        except subprocess.TimeoutExpired:
            pass
        if self._child.returncode != 0:  # the group: the child if it still runs, an X server it left
            try:
                os.killpg(self._child.pid, signal.SIGTERM)
            except (ProcessLookupError, PermissionError):
                pass
        self._child.wait()
        self._stdout.close()
        self._log.close()
        shutil.rmtree(self.folder, ignore_errors=True)

    def __enter__(self) -> Painter:
        return self

    def __exit__(self, kind, value, tb) -> None:
        self.close(now=kind is not None)


def _serve(folder: Path) -> None:
    """The child: draw each announced job into folder/NAME, answer 'ok NAME' or 'error NAME REASON'
    (on the stdout it was started with; anything the libraries print goes to stderr, the log)."""
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    import matplotlib  # noqa: F401 (imported before the first job, while the run is busy)
    import pyvista  # noqa: F401

    from textile_fenicsx.plot import plotting

    with plotting.offscreen():
        for line in sys.stdin:
            jobs = pickle.loads((folder / line.strip()).read_bytes())
            for name, kind, (a, b, c) in jobs:
                try:
                    getattr(plotting, KINDS[kind])(a, b, folder / name, c)
                    answer = f"ok {name}"
                except Exception as e:  # reported to the run, which raises it naming the figure
                    traceback.print_exc()
                    answer = f"error {name} {type(e).__name__}: {e}".replace("\n", " ")
                print(answer, file=answers, flush=True)
    shutil.rmtree(folder, ignore_errors=True)  # stdin closed: the run has its figures, or has ended


if __name__ == "__main__":
    _serve(Path(sys.argv[1]))  # its X server stopped, every answer flushed: no interpreter teardown
    os._exit(0)  # (VTK's took 0.1-0.3 s, for which the run waited in `close`)
