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
        return int(run() or 0)
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
