"""Model files: versioned YAML, validated on load, written atomically.

Each model kind names the class that reads it as a lazy import string, so loading an SDPI file
never imports the diagnose tool, and the diagnose tool's extended model loads like any other.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

import yaml

from .atomic import atomic_write
from .errors import ModelError
from .protocols import Model
from .yamlfile import read_yaml

FORMAT = "gma-ffc-model"
VERSION = 2              # 2: output_sign (falling actuators); version-1 files still load
KINDS: dict[str, str] = {
    "sdpi": "gma_ffc.model:SDPIModel",
    "mpi": "gma_ffc.model:SDPIModel",
    "extended": "gma_ffc.extended:ExtendedModel",
}


def _class_for(kind: str) -> Any:
    target = KINDS.get(kind)
    if target is None:
        raise ModelError(f"unknown model kind {kind!r}; known kinds: {', '.join(sorted(KINDS))}")
    module, _, name = target.partition(":")
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise ModelError(f"model kind {kind!r} is not available in this installation ({exc})") from None


def model_from_dict(d: Any, source: str = "<dict>") -> Model:
    """Build the model a dict describes; ModelError (naming `source`) if it is not a valid model."""
    if isinstance(d, str) and d.lstrip().split(",", 1)[0].split(";", 1)[0].split("\t", 1)[0] == "time_s":
        # `reload --model` and a config's `model` key have no recording's place: say what goes where
        raise ModelError(f"{source} is a recording, not a model file: the model (--model, or a config's 'model' "
                         "key) is a file from gma-ffc identify (or diagnose's extended_model.yaml); a recording "
                         "goes where a command reads one")
    if not isinstance(d, dict):
        raise ModelError(f"{source}: not a model file (expected a YAML mapping)")
    if d.get("format") != FORMAT:
        raise ModelError(f"{source}: not a gma-ffc model file (format is {d.get('format')!r}, expected {FORMAT!r})")
    version = d.get("version")
    if not isinstance(version, int) or version > VERSION or version < 1:
        raise ModelError(f"{source}: model file version {version!r} is not supported (this gma-ffc reads 1..{VERSION})")
    if "kind" not in d:
        raise ModelError(f"{source}: missing key 'kind' (the model kind: one of {', '.join(sorted(KINDS))})"
                         f"{_kind_advice(d)}")
    kind = d.get("kind")
    try:
        return _class_for(str(kind)).from_dict(d)
    except ModelError as exc:
        if str(exc).startswith(source):
            raise
        raise ModelError(f"{source}: {exc}") from None


def _kind_advice(d: dict[str, Any]) -> str:
    """What to add for a file without `kind`: the kind its keys make it (an extended model has a base;
    a play model is sdpi with a stress range, mpi without), or '' when its keys say nothing."""
    if "base" in d:
        kind = "extended"
    elif "play" in d:
        kind = "sdpi" if d.get("stress_range_MPa") is not None else "mpi"
    else:
        return ""
    return f"; its keys make it {kind}: add the line 'kind: {kind}'"


def load_model(path: str | Path) -> Model:
    """Read and validate a model file of any registered kind."""
    return model_from_dict(read_yaml(path, "model file", ModelError), str(path))


def save_model(model: Model, path: str | Path) -> None:
    """Write `model.to_dict()` as YAML; the file appears whole or not at all."""
    d = model.to_dict()
    header = (f"# gma-ffc model ({d.get('kind')}). Units: drive in A (or V), displacement in um, stress in MPa,\n"
              "# compression negative. Edit with care: the file is validated on load.\n")
    with atomic_write(path, "w", encoding="utf-8") as fh:
        fh.write(header)
        yaml.safe_dump(d, fh, sort_keys=False, default_flow_style=None, width=100)
