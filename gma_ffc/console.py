"""The CLI contract's error handling, shared by every console entry point (gma-ffc, hil_sim and
its emulators): errors become one line on stderr and exit 2 (bad input) or 1 (run-time fault).
It lives below `cli` so that the simulator's commands can use it without importing the CLI."""

from __future__ import annotations

import os
import sys
from typing import Callable

from .errors import GmaError


def dispatch(where: str, run: Callable[[], int | None]) -> int:
    """Run a parsed subcommand under the CLI contract: errors become one line on stderr and
    exit 2 (bad input, including a path that cannot be read or written) or 1 (run-time fault or
    bug); GMA_FFC_DEBUG=1 re-raises for the traceback. Shared by every console entry point;
    `where` prefixes the message ("gma-ffc simulate")."""
    try:
        code = int(run() or 0)
        sys.stdout.flush()                 # here, where a closed pipe is caught, not at the interpreter's exit
        return code
    except BrokenPipeError:
        return _reader_gone()
    except GmaError as exc:
        if os.environ.get("GMA_FFC_DEBUG"):
            raise
        print(f"{where}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except OSError as exc:
        if os.environ.get("GMA_FFC_DEBUG"):
            raise
        print(f"{where}: error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{where}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug, not bad input: one line, exit 1, traceback on request
        if os.environ.get("GMA_FFC_DEBUG"):
            raise
        print(f"{where}: internal error: {type(exc).__name__}: {exc} "
              f"(GMA_FFC_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1


SIGPIPE_EXIT = 141   # 128 + SIGPIPE: what a shell reports for a command whose reader went away


def _reader_gone() -> int:
    """The reader of stdout closed it (`gma-ffc identify ... | head -2`): stop quietly, as Unix tools
    do; files already written stay. stdout goes to /dev/null so the interpreter's last flush at exit
    cannot fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):    # no file descriptor behind stdout (a test's capture): nothing to redirect
        pass
    return SIGPIPE_EXIT
