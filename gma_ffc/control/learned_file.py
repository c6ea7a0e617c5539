"""The learned-correction file (`learning.file`, `gma-ffc run --learned`): the one place it is read
and written. A correction belongs to the model it was learned through, so the file carries the
model's fingerprint and a file learned with another model is refused when it is loaded.
"""

from __future__ import annotations

import hashlib
import json
import math
import os

from .. import safe_files
from ..errors import ConfigError, GmaError
from ..protocols import Model
from .learning import RepetitiveLearner

HEADER = "# gma-ffc learned feedforward correction: loaded by `gma-ffc run --learned FILE`\n"


def model_fingerprint(model: Model) -> str:
    """A short hash of the model's data: a learned correction belongs to the model it was learned through."""
    return hashlib.sha256(json.dumps(model.to_dict(), sort_keys=True, default=str).encode()).hexdigest()[:16]


def load_learned(learner: RepetitiveLearner, path: str) -> None:
    """Take the correction saved at `path` if there is one (a first run has none)."""
    if not os.path.exists(path):
        return
    from ..yamlfile import read_yaml

    learner.load_dict(read_yaml(path, "learned-correction file", ConfigError), path)


def save_learned(learner: RepetitiveLearner, path: str, output_dirs: tuple[str, ...] = ()) -> None:
    """Write the correction whole or not at all (an interrupted save keeps the previous file), never
    through a link and never outside `output_dirs` (`gma_ffc.safe_files`)."""
    import yaml

    with safe_files.replace(path, output_dirs, safe_files.LEARNED) as fh:
        fh.write(HEADER)
        yaml.safe_dump(learner.to_dict(), fh, sort_keys=False)


def save_if_learned(learner: RepetitiveLearner | None, path: str | None, output_dirs: tuple[str, ...] = ()) -> str:
    """At the end of a run: keep the best correction for the next one, and only one measured better
    than feedforward (the learner's events say when there was none). The outcome is the learner's
    `saved` (the last-exit record keeps it for `gma-ffc stop`). Returns '' or what went wrong."""
    if learner is None:
        return ""
    if path is None:
        learner.saved = {"file": None, "saved": False, "why": "no learning.file (or --learned) to save it to"}
        return ""
    if not learner.saveable:
        why = "no correction measured better than feedforward"
        learner.saved = {"file": path, "saved": False, "why": why}
        learner.note(math.nan, f"not saved to {path}: {why}")
        return ""
    try:
        save_learned(learner, path, output_dirs)
    except (OSError, GmaError) as exc:
        learner.saved = {"file": path, "saved": False, "why": f"the save failed: {exc}"}
        return f"could not save the learned correction to {path}: {exc}"
    learner.saved = {"file": path, "saved": True}
    learner.note(math.nan, f"saved to {path}")
    return ""
