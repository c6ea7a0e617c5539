"""What one tick did, and the parts that watch every tick (ros2_control's broadcasters).

The runner fills one preallocated `Tick` per tick, after the write (and on a fault tick, with
the safe current as the command), then hands it to each `Broadcaster` in turn: the telemetry
recorder, and any part plugged in: by the builder (`Parts.plugins`, ticked before the recorder so
the columns they fill are in the row, as the model-fit monitor's prediction) or with
`ControllerManager.attach` after it, without a change to the loop; the state broadcaster reads the same record when a status is
asked for, so it costs the loop nothing. A broadcaster's `on_tick` runs on the hot path:
it reads the record, allocates nothing and logs nothing. `on_setup` runs off it, at the start
and after every reload, with the setup (model, law, limits) the ticks that follow will use;
`prepare` before that, in the reloading thread (the loop's work of a reload, done off the loop);
`on_start` as each run starts; `status_fields` adds to the controller's status.
"""

from __future__ import annotations

import math
from typing import Any

from ..drivers import Inputs

# Bits of `Tick.outside_model` (and of the telemetry column of that name).
OUTSIDE_DRIVE = 1     # the law asked for a drive beyond the identified range
OUTSIDE_STRESS = 2    # the stress was beyond the identified range (the model clamped it)


class Tick:
    """One tick's data: preallocated once, overwritten every tick; between ticks, the loop's last
    values (what the state broadcaster reports)."""

    __slots__ = ("time_s", "t", "inputs", "reference_um", "command_A", "current_A", "current_read", "stress_MPa",
                 "displacement_um", "correction_um", "outside_model", "limited_by", "faulted")

    def __init__(self, inputs: Inputs) -> None:
        self.inputs = inputs            # the driver's reading this tick (force, current, displacement)
        self.time_s = 0.0               # when the tick started, from the first deadline (telemetry's time)
        self.t = 0.0                    # the tick's nominal time (its deadline): what the law used
        self.reference_um = math.nan    # the reference for the tick's own instant (a fault tick keeps the last)
        self.command_A = math.nan       # the last command the amplifier got: written, or a safe-current write
        self.current_A = math.nan       # measured, or the command where the driver measures none
        self.current_read = False       # whether current_A was measured this tick (not the command standing in)
        self.stress_MPa = math.nan      # the last good stress
        self.displacement_um = math.nan  # the tick's displacement reading
        self.correction_um = 0.0        # the learner's correction in the command (0 without learning)
        self.outside_model = 0          # OUTSIDE_DRIVE | OUTSIDE_STRESS
        self.limited_by = ""            # safety.NOT_LIMITED or the limit that changed the command
        self.faulted = False            # the tick ended on the fault path


class Broadcaster:
    """A part that watches every tick; subclass and override `on_tick` (and `on_setup` if needed)."""

    on_the_loop = True   # False: the part has no `on_tick` and the loop does not call it

    def on_setup(self, setup: Any) -> None:
        """The setup (`builder.Setup`) the next ticks use: at the start, and after every reload."""

    def prepare(self, setup: Any) -> None:
        """A reload's setup, before the loop adopts it, in the reloading thread: do the slow part
        here (`on_setup` then runs between two ticks). Raise a GmaError to refuse the reload."""

    def on_start(self, setup: Any) -> None:
        """A run starts: the driver is open and the recorder has its columns; off the loop."""

    def status_fields(self) -> dict[str, Any]:
        """Keys this part adds to the controller's status (any thread)."""
        return {}

    def on_tick(self, tick: Tick) -> None:  # pragma: no cover - interface
        raise NotImplementedError
