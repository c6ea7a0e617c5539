"""The `gma-ffc` console script: one parser, one module per subcommand (see docs/cli.md).

Each subcommand module exposes ``register(subparsers)``, which adds its parser and sets
``func(args) -> int``. Errors raised on purpose (`GmaError`) become one line on stderr and the
contract's exit code (2 bad input, 1 run-time fault); nothing else prints a traceback unless
``GMA_FFC_DEBUG=1``.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
from typing import Any, Sequence

from ..console import dispatch

# What argparse takes for a negative number rather than an option: its own forms (-3, -.5, -2.5) and
# scientific notation (-1e9, -2.5E-3)
NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")
# Order here is the order in `gma-ffc --help`.
SUBCOMMAND_MODULES = ("identify", "simulate", "invert", "diagnose", "run", "service", "demo")

DESCRIPTION = """\
Model, invert and control hysteretic giant magnetostrictive actuators (GMA) with a
stress-dependent Prandtl-Ishlinskii (SDPI) model.

typical session:
  gma-ffc identify rec_11MPa.csv rec_15MPa.csv rec_19MPa.csv -o model.yaml
  gma-ffc simulate --model model.yaml rec_24MPa.csv -o predicted.csv
  gma-ffc invert --model model.yaml reference.csv -o drive.csv
  gma-ffc diagnose --model model.yaml long_run.csv --out diagnosis/
  gma-ffc start --config config/sim.yaml && gma-ffc status && gma-ffc stop
  gma-ffc demo            # everything above on the built-in simulated actuator
"""


class _Parser(argparse.ArgumentParser):
    """argparse, but bad usage is one line and exit 2, as the CLI contract says, and a negative number
    in scientific notation is a value: argparse took `--limit -1e9 1e9` for an option `-1e9` and said
    only "expected 2 arguments"."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_NUMBER

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="gma-ffc", description=DESCRIPTION,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"gma-ffc {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except KeyboardInterrupt:
        # Ctrl-C while the subcommands load (numba's import alone takes about half a second, on
        # every command) printed a 50-line traceback; as `dispatch` does for one at work
        print("gma-ffc: interrupted", file=sys.stderr)
        return 130
    return dispatch(f"gma-ffc {args.command}", lambda: args.func(args))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
