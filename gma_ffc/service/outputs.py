"""What a service run writes, checked before anything starts (before the driver opens).

No output may be a file the run reads (the model, a playback reference, the sim's plant config:
a run replaying its own telemetry truncated the recording it played). Each output must be
writable where `gma_ffc.safe_files` allows it (no link, inside output_dirs, not someone else's
file, in a folder that takes a new file), and no two outputs may be one file.
A refusal is one `OutputRefused` line naming the path and the setting the user gave (exit 2), so
nothing fails after the run naming a temporary file or a config key the user never set.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import Any, Sequence

from .. import safe_files
from ..atomic import same_file
from ..errors import ConfigError


@dataclass(frozen=True)
class Output:
    """One file the run writes, where it may land, and what it is (its `kind.setting` names it)."""

    path: str
    roots: tuple[str, ...]
    kind: safe_files.Kind


def outputs_of(cfg: Any, config_path: str, stats_json: str | os.PathLike | None) -> list[Output]:
    """The run's outputs in the order the user is told about them: the config's, then the options'."""
    dirs = tuple(getattr(cfg, "output_dirs", ()))
    out: list[Output] = []
    telemetry = getattr(cfg, "telemetry", {}).get("path")
    if telemetry:
        out.append(Output(telemetry, dirs, safe_files.telemetry_kind(config_path)))
        out.append(Output(telemetry + ".lock", dirs, safe_files.TELEMETRY_LOCK))
    learned = getattr(getattr(cfg, "learning", None), "file", None)
    if learned:
        setting = getattr(cfg, "learned_setting", safe_files.LEARNED.setting)
        out.append(Output(learned, dirs, replace(safe_files.LEARNED, setting=setting)))
    if stats_json is not None:
        out.append(Output(os.fspath(stats_json), (), safe_files.STATS))
    return out


def inputs_of(cfg: Any) -> list[tuple[str, str]]:
    """(config key, path) of each file the run reads and must not write over. The learned
    correction is read and written back on purpose, so it is not here."""
    found = [("model", getattr(cfg, "model", None))]
    reference = getattr(cfg, "reference", {})
    if reference.get("kind") == "playback":
        found.append(("reference.file", reference.get("file")))
    found.append(("driver.plant_config", getattr(cfg, "driver", {}).get("plant_config")))
    return [(key, str(path)) for key, path in found if isinstance(path, (str, os.PathLike)) and path]


def check_inputs_exist(inputs: Sequence[tuple[str, str]], config_path: str) -> None:
    """Refuse a file the run reads that is not there, before the outputs are judged: a config copied
    to another folder has lost its model, and was told so only after its telemetry was mended."""
    for key, path in inputs:
        if not os.path.exists(path):
            raise ConfigError(f"{path}: no such file (config key '{key}' in {config_path}; a relative path "
                              "resolves against the config's folder)")


def check_outputs(outputs: Sequence[Output], inputs: Sequence[tuple[str, str]] = ()) -> None:
    """Refuse an output over an input, one that cannot be written safely, or two that are one file."""
    for output in outputs:
        for key, path in inputs:
            if same_file(output.path, path):
                raise safe_files.OutputRefused(
                    f"{output.kind.setting} {output.path} is the file config key '{key}' reads ({path}): "
                    f"the run would overwrite it; choose another {output.kind.setting}")
    for output in outputs:
        safe_files.check_writable(output.path, output.roots, output.kind)
    for j, later in enumerate(outputs):
        for earlier in outputs[:j]:
            if same_file(later.path, earlier.path):
                raise safe_files.OutputRefused(
                    f"{later.kind.setting} {later.path} is the same file as {earlier.kind.setting}: "
                    f"two outputs cannot share a file; choose another {later.kind.setting}")
