"""`gma-ffc invert`: placeholder until its issue lands (it exits 1 and says so)."""

from __future__ import annotations

import argparse

from ..errors import FaultError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("invert", help="(not built yet)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    raise FaultError("'invert' is not built yet")
