"""Exception types that map onto the CLI contract's exit codes.

`InputError` (exit 2) is the user's to fix: a bad file, config, register value or argument.
`FaultError` (exit 1) is a fault at run time: hardware, comms, an internal failure.
Both carry one clear sentence; the CLI prints it without a traceback.
"""

from __future__ import annotations


class GmaError(Exception):
    """Base of every error gma-ffc raises on purpose."""

    exit_code = 1


class InputError(GmaError):
    """Bad input: the message says what is wrong and what to fix."""

    exit_code = 2


class RecordingError(InputError):
    """A recording file violates docs/recordings.md."""


class ModelError(InputError):
    """A model file is damaged, inconsistent, or used outside its validity."""


class ConfigError(InputError):
    """A configuration file is invalid; the message names the key."""


class FaultError(GmaError):
    """A fault at run time (comms, device, internal)."""


class NotRunningError(FaultError):
    """Nobody answers on the control socket: no controller is running there."""


class NoAnswerError(FaultError):
    """Something holds the control socket but gave no reply in time (a controller stopped, stuck or starved)."""
