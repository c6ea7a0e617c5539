"""Reference signals evaluated one sample at a time without allocating containers.

Periodic references (sine, triangle, multi-sine) may be evaluated ahead by `lead_s`, the known
output latency of the rig, so the displacement arrives on time. Playback walks a preallocated
table with a moving index (time only goes forward), so a tick costs O(1).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import ConfigError, RecordingError
from ..recordings import read_recording

TWO_PI = 2.0 * math.pi


class Reference:
    """`value(t)` is the reference displacement (um) at run time t (s)."""

    lead_s: float = 0.0

    def value(self, t: float) -> float:  # pragma: no cover - interface
        raise NotImplementedError

    def batch(self, t: np.ndarray) -> np.ndarray:
        """Vectorised evaluation for tests and reports (not used on the hot path)."""
        return np.array([self.value(float(x)) for x in np.asarray(t, dtype=float)])

    def peak_um(self) -> float:  # pragma: no cover - interface
        """The largest |value| the reference can take (a bound, checked against the model's reach)."""
        raise NotImplementedError


class Sine(Reference):
    def __init__(self, frequency_hz: float, amplitude_um: float, offset_um: float = 0.0,
                 phase_deg: float = -90.0, lead_s: float = 0.0) -> None:
        self.w = TWO_PI * frequency_hz
        self.a = amplitude_um
        self.c = offset_um
        self.phi = math.radians(phase_deg)
        self.lead_s = lead_s

    def value(self, t: float) -> float:
        return self.c + self.a * math.sin(self.w * (t + self.lead_s) + self.phi)

    def peak_um(self) -> float:
        return abs(self.c) + abs(self.a)


class Triangle(Reference):
    """Starts at its minimum (offset - amplitude), peaks at half a period."""

    def __init__(self, frequency_hz: float, amplitude_um: float, offset_um: float = 0.0,
                 lead_s: float = 0.0) -> None:
        self.f = frequency_hz
        self.a = amplitude_um
        self.c = offset_um
        self.lead_s = lead_s

    def value(self, t: float) -> float:
        x = ((t + self.lead_s) * self.f) % 1.0
        tri = 4.0 * x - 1.0 if x < 0.5 else 3.0 - 4.0 * x
        return self.c + self.a * tri

    def peak_um(self) -> float:
        return abs(self.c) + abs(self.a)


class MultiSine(Reference):
    def __init__(self, components: list[dict[str, float]], offset_um: float = 0.0, lead_s: float = 0.0) -> None:
        self.w = tuple(TWO_PI * c["frequency_hz"] for c in components)
        self.a = tuple(c["amplitude_um"] for c in components)
        self.phi = tuple(math.radians(c.get("phase_deg", 0.0)) for c in components)
        self.n = len(components)
        self.c = offset_um
        self.lead_s = lead_s

    def value(self, t: float) -> float:
        tt = t + self.lead_s
        y = self.c
        w, a, phi = self.w, self.a, self.phi
        for k in range(self.n):
            y += a[k] * math.sin(w[k] * tt + phi[k])
        return y

    def peak_um(self) -> float:
        return abs(self.c) + sum(abs(a) for a in self.a)


class Playback(Reference):
    """Linear interpolation in a recorded reference; holds the last value (or loops) at the end."""

    def __init__(self, time_s: np.ndarray, reference_um: np.ndarray, loop: bool = False,
                 lead_s: float = 0.0, source: str = "<memory>") -> None:
        t = np.asarray(time_s, dtype=float)
        r = np.asarray(reference_um, dtype=float)
        if len(t) < 2 or not np.all(np.isfinite(r)):
            raise RecordingError(f"{source}: a playback reference needs at least two finite samples")
        self.t = (t - t[0]).tolist()    # Python floats: faster per element than numpy scalars
        self.r = r.tolist()
        self.n = len(self.t)
        self.duration = self.t[-1]
        self.loop = loop
        self.lead_s = lead_s
        self.i = 0

    def value(self, t: float) -> float:
        tt = t + self.lead_s
        if self.loop and self.duration > 0.0:
            tt = tt % self.duration
        ts, rs = self.t, self.r
        if tt <= 0.0:
            return rs[0]
        if tt >= self.duration:
            return rs[-1]
        i = self.i
        if ts[i] > tt:          # time went back (loop wrap): restart the walk
            i = 0
        while ts[i + 1] < tt:
            i += 1
        self.i = i
        t0, t1 = ts[i], ts[i + 1]
        return rs[i] + (rs[i + 1] - rs[i]) * (tt - t0) / (t1 - t0)

    def peak_um(self) -> float:
        return max(abs(v) for v in self.r)


def build_reference(section: dict[str, Any], preview_s: float = 0.0) -> Reference:
    """A reference from a validated `reference` config section.

    `preview_s` is added to the configured lead: a model that contains a transport delay (an
    extended model from `gma-ffc diagnose`) can only be inverted by asking for the reference that
    far ahead.
    """
    kind = section["kind"]
    lead = section.get("lead_s", 0.0) + max(0.0, float(preview_s))
    if kind == "sine":
        return Sine(section["frequency_hz"], section["amplitude_um"], section["offset_um"],
                    section["phase_deg"], lead)
    if kind == "triangle":
        return Triangle(section["frequency_hz"], section["amplitude_um"], section["offset_um"], lead)
    if kind == "multisine":
        return MultiSine(section["components"], section["offset_um"], lead)
    if kind == "playback":
        try:
            rec = read_recording(section["file"], require=("time_s", "reference_um"))
        except RecordingError as exc:
            raise ConfigError(f"config key 'reference.file': {exc}") from None
        return Playback(rec.time_s, rec.columns["reference_um"], section["loop"], lead, rec.source)
    raise ConfigError(f"config key 'reference.kind': unknown kind {kind!r}")
