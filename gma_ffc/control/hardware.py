"""The driver supervisor: ros2_control's resource manager for the one hardware interface.

It takes the driver through its lifecycle (open = configure, activate, deactivate, close), writes
the safe current with retries, and reconnects with exponential backoff. Failures become faults
in the `FaultLog`, never exceptions out of here; which fault leads to a reconnect and which to a
stop is the fault table's call, made by the runner (`manager`). The tick's own `read` and
`write` go to the driver directly: nothing stands between the loop and the hardware.
"""

from __future__ import annotations

import time
from typing import Any, Callable

from ..drivers import REFUSED, DriverError, DriverProtocol
from . import safety
from .faults import FaultLog, driver_fault

SAFE_RETRY_PAUSE_S = 0.05     # between safe-current tries on a failing link: a device gets time to answer


class DriverSupervisor:
    """Lifecycle, safe write and reconnect for `driver`; `at_safe` says the last write was the safe one."""

    def __init__(self, driver: DriverProtocol, simulated: bool, comms: dict[str, Any], faults: FaultLog) -> None:
        self.driver = driver
        self.simulated = simulated       # a simulated clock: no real-time retry of the safe write
        self.comms = comms
        self.faults = faults
        self.reconnects = 0
        self.at_safe = False

    def open(self) -> str:
        """Configure (connect): '' when open, else the comms fault raised."""
        try:
            self.driver.open()
            return ""
        except DriverError as exc:
            name = driver_fault(exc)
            self.faults.raise_fault(name, f"cannot open the driver: {exc}")
            return name

    def activate(self) -> None:
        """Output on, just before the first command (never by a write)."""
        self.driver.activate()

    def write_safe(self, safe_A: float) -> bool:
        """The safe current, at once. On a failing link keep retrying (with a reconnect between
        tries) for `comms.safe_retry_s` of real time; a final failure is the fault
        `safe_write_failed`, never raised. True when the write got through."""
        give_up = time.monotonic() + (0.0 if self.simulated else self.comms["safe_retry_s"])
        while True:
            try:
                self.driver.safe(safe_A)
                self.at_safe = True
                self.faults.clear(safety.SAFE_WRITE_FAILED)
                return True
            except Exception as exc:  # the device may be gone; keep trying for a while
                if time.monotonic() >= give_up:
                    self.faults.raise_fault(safety.SAFE_WRITE_FAILED,
                                            f"could not write the safe current: {type(exc).__name__}: {exc}")
                    return False
            time.sleep(SAFE_RETRY_PAUSE_S)
            try:
                self.driver.reconnect()
            except Exception:
                pass

    def coil_path_at_safe(self, safe_A: float) -> tuple[float, ...] | None:
        """The currents the coil has carried since the last safe write, until the output goes on
        again: the safe current, then 0 A when the driver's `safe()` switched the output off. None
        when the last safe write did not get through: what the coil did meanwhile is not known."""
        if not self.at_safe:
            return None
        return (safe_A, 0.0) if getattr(self.driver, "switches_off_on_safe", False) else (safe_A,)

    def reconnect(self, wait: Callable[[float], bool], safe_A: float | None = None) -> bool:
        """Reconnect with exponential backoff; True when the driver answers again. `wait(s)`
        sleeps on the runner's clock and says whether a stop came meanwhile. With `safe_A`, a safe
        current that did not get through is written first, before the output goes on again."""
        comms = self.comms
        delay = comms["backoff_initial_s"]
        attempt = 0
        while comms["max_attempts"] == 0 or attempt < comms["max_attempts"]:
            attempt += 1
            if wait(delay):
                return False
            try:
                self.driver.reconnect()
                if safe_A is not None and not self.at_safe:
                    self._safe_after_reconnect(safe_A)
                self.driver.activate()         # safe() may have switched the output off
            except DriverError as exc:
                self.driver.last_error = str(exc)
                if exc.reason == REFUSED:        # activate's output_enable: no reconnect adds a register
                    self.faults.raise_fault(safety.REGISTER_REFUSED, str(exc))
                    return False
                delay = min(delay * 2.0, comms["backoff_max_s"])
                continue
            except Exception as exc:
                self.faults.raise_fault(safety.EXCEPTION, f"reconnect raised {type(exc).__name__}: {exc}")
                return False
            self.reconnects += 1
            self.faults.clear(safety.COMMS_ERROR)
            self.faults.clear(safety.COMMS_TIMEOUT)
            return True
        self.faults.raise_fault(safety.RECONNECT_FAILED, f"gave up after {attempt} reconnect attempts")
        return False

    def _safe_after_reconnect(self, safe_A: float) -> None:
        """The safe current the fault could not write, now the link is back: the amplifier is
        known safe again, so `safe_write_failed` no longer holds (it stays in the history)."""
        self.driver.safe(safe_A)
        self.at_safe = True
        self.faults.clear(safety.SAFE_WRITE_FAILED)

    def deactivate(self) -> None:
        """Output off, after the safe current; a failure is the fault `deactivate_failed`."""
        try:
            self.driver.deactivate()
        except Exception as exc:   # after the safe current: the output may still be on, say so
            self.faults.raise_fault(safety.DEACTIVATE_FAILED,
                                    f"output not switched off: {type(exc).__name__}: {exc}")

    def close(self) -> None:
        try:
            self.driver.close()
        except Exception as exc:
            self.faults.raise_fault(safety.CLOSE_FAILED, f"{type(exc).__name__}: {exc}")
