"""The `textile-fenicsx` command line: parse (arguments.py), run the command (commands.py), and
turn what it raised into an exit code and one message.

Exit codes (docs/errors.md): 0 success; 1 the run failed (the contact iteration
did not converge, a singular or non-finite solve, a file that cannot be written, an internal
error); 2 bad input or usage (the message names the culprit); 130 interrupted (Ctrl-C, SIGTERM).
Under MPI an error on any rank prints its message and ends every rank (MPI_Abort), so no rank
waits forever in a collective call.
"""

import logging
import os
import signal
import sys
import traceback

from textile_fenicsx.cli.arguments import build_parser
from textile_fenicsx.common import interrupts
from textile_fenicsx.common.errors import MeshError, OutputError, TextileError
from textile_fenicsx.common.files import abandon_outputs

__all__ = ["EXIT_FAILED", "EXIT_INPUT", "EXIT_INTERRUPTED", "EXIT_OK", "build_parser", "main"]

EXIT_OK, EXIT_FAILED, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


def _interrupt(signum: int, _frame: object) -> None:
    interrupts.handled()
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _env_rank() -> int:
    """This process's MPI rank as mpirun tells it (0 outside mpirun), without importing MPI."""
    return int(os.environ.get("OMPI_COMM_WORLD_RANK", os.environ.get("PMI_RANK", "0")))


def _line(text: str, rank: int = 0) -> str:
    """An error's line on stderr, naming the rank other than 0 that prints it."""
    return f"textile-fenicsx: error{f' (rank {rank})' if rank else ''}: {text}"


def _error_line(text: str) -> str:
    """An error's line as printed from a watcher thread (interrupts.py)."""
    return _line(text, _env_rank())


def _interrupted_text(signal_name: str) -> str:
    return f"interrupted ({signal_name}); no output was written"


def _interrupted(signum: int) -> str:
    """The message of a run ended by a signal from interrupts.py's watcher."""
    return _error_line(_interrupted_text(signal.Signals(signum).name))


def _fail(code: int, message: str, collective: bool = False) -> int:
    """Report an error from this rank and, under MPI, end every rank with the exit code.
    collective: every rank raised the same error at the same place (files.claim_output): rank 0
    reports it and every rank returns the code."""
    rank, size = 0, 1
    if "mpi4py.MPI" in sys.modules:
        from mpi4py import MPI

        rank, size = MPI.COMM_WORLD.rank, MPI.COMM_WORLD.size
    if collective and size > 1:
        if rank == 0:
            print(_line(message), file=sys.stderr, flush=True)
        return code
    print(_line(message, rank if size > 1 else 0), file=sys.stderr, flush=True)
    if size > 1:
        sys.stderr.flush()
        MPI.COMM_WORLD.Abort(code)
    return code


def _log_to_stderr() -> None:
    """Progress lines (the library's logging, INFO) to stderr, from rank 0 only."""
    rank = _env_rank() if "mpi4py.MPI" in sys.modules or "OMPI_COMM_WORLD_RANK" in os.environ else 0
    root = logging.getLogger("textile_fenicsx")
    root.handlers.clear()
    if rank == 0:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(message)s"))
        root.addHandler(handler)
        root.setLevel(logging.INFO)
    else:
        root.addHandler(logging.NullHandler())
    root.propagate = False


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "run"):
        parser.print_help()
        return EXIT_INPUT
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)
    interrupts.watch(_interrupted, abandon_outputs, EXIT_INTERRUPTED, _error_line)
    from textile_fenicsx.common.errors import SolverError

    _log_to_stderr()
    try:
        return args.run(args)
    except TextileError as e:
        return _fail(EXIT_INPUT, str(e), getattr(e, "collective", False))
    except (SolverError, MeshError, OutputError) as e:
        return _fail(EXIT_FAILED, str(e), getattr(e, "collective", False))
    except KeyboardInterrupt as e:
        return _fail(EXIT_INTERRUPTED, _interrupted_text(str(e) or "SIGINT"))
    except OSError as e:
        return _fail(EXIT_FAILED, f"cannot read or write {e.filename or 'a file'}: {e.strerror or e}",
                     getattr(e, "collective", False))
    except Exception as e:  # a bug: say so, with the traceback, and still end every rank
        traceback.print_exc()
        return _fail(EXIT_FAILED, f"internal error {type(e).__name__}: {e}")


if __name__ == "__main__":
    sys.exit(main())
