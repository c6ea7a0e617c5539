"""Pieces the subcommands share: reading inputs with the contract's errors, stress handling."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import InputError
from ..protocols import Model
from ..recordings import Recording, read_recording


def existing_output_dir_parent(path: str) -> Path:
    p = Path(path)
    if p.parent and not p.parent.exists():
        raise InputError(f"output folder {p.parent} does not exist")
    return p


def read_all(paths: Sequence[str], require: Sequence[str], group: str | None = None) -> list[Recording]:
    return [read_recording(p, require=require, group=group) for p in paths]


def add_group_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--group", metavar="NAME",
                   help="for .tdms and .h5 recordings: the group holding the channels (needed when there are several)")


def stress_for(model: Model, rec: Recording, override: float | None) -> np.ndarray | float | None:
    """The stress to run `model` at for `rec`: --stress wins, else the recording's column."""
    if override is not None:
        return float(override)
    if rec.stress_MPa is not None:
        return rec.stress_MPa
    if model.stress_range_MPa is not None:
        lo, hi = model.stress_range_MPa
        raise InputError(f"{rec.source}: no stress_MPa column, and this {model.kind} model depends on stress "
                         f"(identified on {lo:.3g}..{hi:.3g} MPa); add the column or pass --stress MPA")
    return None


def check_drive_name(model: Model, rec: Recording) -> None:
    name = model.drive_name
    if rec.drive_name != name:
        raise InputError(f"{rec.source}: drive column is {rec.drive_name} but the model was identified on {name}")


def add_initial_state_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--initial-state", default="estimate", metavar="RULE", type=_initial_state,
                   help="hysteresis state at the first sample: estimate (default: fitted to the measured "
                        "displacement where there is one, else consistent with the drive's first monotone "
                        "stretch), relaxed, or drive:VALUE (relaxed at that drive)")


def _initial_state(text: str) -> Any:
    from ..initial_state import InitialStateSpec

    try:
        return InitialStateSpec.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_stress_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--stress", type=float, metavar="MPA",
                   help="constant stress in MPa (compression negative) for recordings without stress_MPa")
