"""Learning feedforward: repetitive control on top of the inverse model (issue 12).

The inverse SDPI cancels the hysteresis it modelled; what it does not model (eddy lag, a delay
the lead does not cover exactly, dynamics, a model error) stays as a tracking error that, for a
periodic reference, repeats every period. The learner keeps a correction `c` in the OUTPUT
domain, one value per phase of the period, and the controller feeds the inverse with `r + c`
instead of `r`: the hysteresis stays handled by the model, and the learning sees a near-linear
plant P (reference in, displacement out, |P| ~ 1).

After each clean period k the correction is updated from that period's error e = r - y::

    c_{k+1}[j] = Q{ f * c_k[j] + L * e_k[j + m] },   |c| <= bound

with L the learning gain, m a phase lead in samples (covers latency the controller's lead does
not), f a forgetting factor and Q a low-pass robustness filter, zero-phase over the circular
period buffer. The filtered error then converges monotonically where |Q (1 - L z^m P)| < 1
(derivation and the choice of defaults: docs/learning.md).

Hot-path contract: `correction()` and `observe()` allocate nothing and log nothing; the period
update runs in a compiled kernel on preallocated buffers. Learning freezes (keeps `c`, learns
nothing) whenever the caller says the tick is not clean (fault, safe current, reconnecting,
ramp, limiter active) and whenever the displacement reading is missing, stuck or absurd; a
period that contained a frozen tick is not learned from. A change of the plant's gain with
stress scales the buffer, and a large one resets it (rule in `_end_period`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np
from numba import njit

from ..errors import ConfigError

if TYPE_CHECKING:
    from ..protocols import Model

TREND = 64                 # per-period RMS values kept for the status


@dataclass(frozen=True)
class LearningConfig:
    """The `learning:` section. Defaults follow docs/learning.md, not a benchmark."""

    kind: str = "off"                   # "off" | "repetitive"
    period_s: float | None = None       # None: from the periodic reference
    gain: float = 0.5                   # L: error halves per period where P ~ 1; margin for |P| up to 2
    filter: str = "zero_phase"          # Q: "zero_phase" (no lag) or "causal" (first order)
    cutoff_hz: float | None = None      # Q's -3 dB point; None: 10 harmonics, at most rate/10
    lead_samples: int = 0               # m: latency the controller's lead_s does not cover
    forgetting: float = 1.0             # f: < 1 lets an old correction fade when the error is gone
    max_correction_um: float = 5.0      # bound on |c|
    max_error_um: float = 50.0          # |r - y| beyond this is an absurd reading: freeze
    stale_ticks: int = 50               # an unchanged displacement reading this long: freeze
    reset_gain_change: float = 0.2      # relative plant-gain change (with stress) that resets c
    file: str | None = None             # learned buffer: loaded at start if present, saved at stop

    @property
    def enabled(self) -> bool:
        return self.kind == "repetitive"

    @classmethod
    def from_mapping(cls, section: Mapping[str, Any] | None, prefix: str = "learning") -> "LearningConfig":
        """Validate a config section; every error names the dotted key."""
        if section is None:
            return cls()
        if not isinstance(section, Mapping):
            raise ConfigError(f"config key '{prefix}' must be a mapping, e.g. {{kind: repetitive}}")
        known = {f.name for f in fields(cls)}
        values: dict[str, Any] = {}
        for key, value in section.items():
            if key not in known:
                raise ConfigError(f"config key '{prefix}.{key}' is unknown (known keys: {', '.join(sorted(known))})")
            values[key] = value
        cfg = cls(**values)
        cfg._check(prefix)
        return cfg

    def _check(self, prefix: str) -> None:
        def bad(key: str, what: str) -> ConfigError:
            return ConfigError(f"config key '{prefix}.{key}' {what}, got {getattr(self, key)!r}")

        def number(key: str, lo: float, hi: float, lo_open: bool = False, optional: bool = False) -> None:
            v = getattr(self, key)
            if v is None and optional:
                return
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise bad(key, "must be a number")
            if v < lo or v > hi or (lo_open and v == lo):
                raise bad(key, f"must be in {'(' if lo_open else '['}{lo:g}, {hi:g}]")

        if self.kind not in ("off", "repetitive"):
            raise bad("kind", "must be 'off' or 'repetitive'")
        if self.filter not in ("zero_phase", "causal"):
            raise bad("filter", "must be 'zero_phase' or 'causal'")
        number("period_s", 0.0, 3600.0, lo_open=True, optional=True)
        number("gain", 0.0, 1.0, lo_open=True)
        number("cutoff_hz", 0.0, 1e6, lo_open=True, optional=True)
        number("forgetting", 0.5, 1.0)
        number("max_correction_um", 0.0, 1e4, lo_open=True)
        number("max_error_um", 0.0, 1e6, lo_open=True)
        number("reset_gain_change", 0.0, 10.0, lo_open=True)
        for key in ("lead_samples", "stale_ticks"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise bad(key, "must be a whole number >= 0")
        if self.file is not None and not isinstance(self.file, str):
            raise bad("file", "must be a path")

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def reference_period_s(section: Mapping[str, Any]) -> float | None:
    """The period of a validated reference section, or None when it is not periodic.

    A multi-sine is periodic with the lowest frequency when every component is a harmonic of it.
    """
    kind = section.get("kind")
    if kind in ("sine", "triangle"):
        return 1.0 / float(section["frequency_hz"])
    if kind == "multisine":
        freqs = [float(c["frequency_hz"]) for c in section["components"]]
        f0 = min(freqs)
        if all(abs(f / f0 - round(f / f0)) < 1e-9 for f in freqs):
            return 1.0 / f0
        return None
    return None


@njit(cache=True, nogil=True)
def _lowpass_circular(x: np.ndarray, a: float, zero_phase: bool) -> None:
    """First-order low-pass y[k] = y[k-1] + a (x[k] - y[k-1]) over a circular buffer, in place.

    One lap settles the filter's state on the periodic signal (its memory is ~1/a samples, and
    a lap is longer); the second lap writes. Zero-phase runs the same filter backwards too, so
    the overall response is |H|^2 with no phase lag.
    """
    n = x.shape[0]
    y = x[n - 1]
    for k in range(n):                       # settle, forwards
        y += a * (x[k] - y)
    for k in range(n):
        y += a * (x[k] - y)
        x[k] = y
    if zero_phase:
        y = x[0]
        for k in range(n - 1, -1, -1):       # settle, backwards
            y += a * (x[k] - y)
        for k in range(n - 1, -1, -1):
            y += a * (x[k] - y)
            x[k] = y


@njit(cache=True, nogil=True)
def _learn_period(c: np.ndarray, e: np.ndarray, gain: float, forgetting: float, lead: int, a: float,
                  zero_phase: bool, bound: float) -> None:
    """c <- clip(Q{f c + L e[. + lead]}, +-bound), in place (see the module docstring)."""
    n = c.shape[0]
    for j in range(n):
        c[j] = forgetting * c[j] + gain * e[(j + lead) % n]
    if a < 1.0:
        _lowpass_circular(c, a, zero_phase)
    for j in range(n):
        if c[j] > bound:
            c[j] = bound
        elif c[j] < -bound:
            c[j] = -bound


def filter_coefficient(cutoff_hz: float, rate_hz: float, zero_phase: bool) -> float:
    """Smoothing factor `a` of the first-order filter whose overall -3 dB point is `cutoff_hz`.

    The zero-phase pair squares the magnitude, so each pass is placed where |H| = 2^-1/4.
    """
    wc = 2.0 * math.pi * cutoff_hz / rate_hz
    if zero_phase:
        wc /= math.sqrt(math.sqrt(2.0) - 1.0)     # 1 / (1 + (w/wp)^2) = 1/sqrt(2) at w = wc
    if wc >= math.pi:
        return 1.0
    return 1.0 - math.exp(-wc)


class RepetitiveLearner:
    """The learned correction of one period, indexed by phase; see the module docstring.

    `gain_of_stress` maps a stress (MPa) to the plant's gain (um per unit of reference, from the
    model); it is evaluated once per period, never in a tick.
    """

    def __init__(self, cfg: LearningConfig, rate_hz: float, period_s: float,
                 gain_of_stress: Any = None, fingerprint: str = "") -> None:
        if not cfg.enabled:
            raise ConfigError("learning is off (learning.kind: repetitive turns it on)")
        n = int(round(period_s * rate_hz))
        if n < 4:
            raise ConfigError(f"config key 'learning.period_s': a period of {period_s:g} s is only {n} samples at "
                              f"{rate_hz:g} Hz; the learner needs at least 4")
        self.cfg = cfg
        self.rate_hz = float(rate_hz)
        self.period_s = float(period_s)
        self.n = n
        self.fingerprint = fingerprint
        self.correction_um = np.zeros(n)       # c: applied
        self._err = np.zeros(n)                # this period's error, by phase
        self._seen = np.zeros(n, dtype=np.bool_)
        cutoff = cfg.cutoff_hz if cfg.cutoff_hz is not None else min(10.0 / period_s, rate_hz / 10.0)
        self.cutoff_hz = cutoff
        self._a = filter_coefficient(cutoff, rate_hz, cfg.filter == "zero_phase")
        self._zero_phase = cfg.filter == "zero_phase"
        self._gain_of_stress = gain_of_stress
        self.trend_rms_um = np.full(TREND, np.nan)
        self.periods = 0                       # periods completed
        self.learned_periods = 0               # periods learned from
        self.frozen_reason = "waiting for the first full period"
        self.frozen_since_s = 0.0
        self.last_event = ""
        self.learned_stress_MPa = math.nan
        self._last_phase = -1
        self._period_clean = False
        self._sum_sq = 0.0
        self._count = 0
        self._stress_sum = 0.0
        self._last_y = math.nan
        self._same_y = 0
        self.last_correction_um = 0.0

    # ---- the tick (allocation-free) --------------------------------------------------------
    def phase(self, t: float) -> int:
        x = (t % self.period_s) / self.period_s * self.n
        k = int(x + 0.5)
        return k - self.n if k >= self.n else k

    def correction(self, t_target: float) -> float:
        """c for the instant the command is meant for (the controller's t + lead)."""
        c = self.correction_um[self.phase(t_target)]
        self.last_correction_um = c
        return c

    def observe(self, t: float, reference_um: float, displacement_um: float, stress_MPa: float,
                ok: bool, why_not: str = "") -> None:
        """Record e = r - y at run time t. `ok` False (with a reason) freezes learning this tick."""
        k = self.phase(t)
        if k < self._last_phase:
            self._end_period(t)
        self._last_phase = k
        y = displacement_um
        if y == self._last_y:
            self._same_y += 1
        else:
            self._same_y = 0
            self._last_y = y
        e = reference_um - y
        if not ok:
            self._freeze(t, why_not or "the controller is not tracking")
        elif y != y or e != e:
            self._freeze(t, "displacement reading missing or NaN")
        elif abs(e) > self.cfg.max_error_um:
            self._freeze(t, f"tracking error beyond learning.max_error_um ({self.cfg.max_error_um:g} um): "
                            "absurd displacement reading")
        elif self.cfg.stale_ticks and self._same_y >= self.cfg.stale_ticks:
            self._freeze(t, f"displacement reading unchanged for {self._same_y} ticks (stuck sensor)")
        else:
            self._err[k] = e
            self._seen[k] = True
            self._sum_sq += e * e
            self._count += 1
            self._stress_sum += stress_MPa
            return

    def freeze(self, t: float, reason: str) -> None:
        """Learn nothing from the current period (a fault, a reconnect, ...); keep c."""
        self._freeze(t, reason)

    def _freeze(self, t: float, reason: str) -> None:
        if self._period_clean or not self.frozen_reason:
            self.frozen_since_s = t
        if self.frozen_reason != reason:
            self.frozen_reason = reason
            self.frozen_since_s = t
        self._period_clean = False

    # ---- once per period -------------------------------------------------------------------
    def _end_period(self, t: float) -> None:
        self.periods += 1
        if self._count:
            self.trend_rms_um[:-1] = self.trend_rms_um[1:]
            self.trend_rms_um[-1] = math.sqrt(self._sum_sq / self._count)
        complete = self._period_clean and bool(self._seen.all())
        if complete:
            stress = self._stress_sum / self._count
            if self._stress_rule(stress):
                _learn_period(self.correction_um, self._err, self.cfg.gain, self.cfg.forgetting,
                              self.cfg.lead_samples, self._a, self._zero_phase, self.cfg.max_correction_um)
                self.learned_periods += 1
            self.frozen_reason = ""
        self._seen[:] = False
        self._sum_sq = 0.0
        self._count = 0
        self._stress_sum = 0.0
        self._period_clean = True     # until a tick of the new period says otherwise

    def _stress_rule(self, stress: float) -> bool:
        """Scale c by the plant's gain change since it was learned; reset it past
        `reset_gain_change` (the learned shape belongs to another plant). True: learn this period."""
        old = self.learned_stress_MPa
        self.learned_stress_MPa = stress
        if self._gain_of_stress is None or old != old or stress == old:
            return True
        g_old, g_new = self._gain_of_stress(old), self._gain_of_stress(stress)
        if not (g_old > 0.0 and g_new > 0.0):
            return True
        ratio = g_new / g_old
        if abs(ratio - 1.0) > self.cfg.reset_gain_change:
            self.correction_um[:] = 0.0
            self.last_event = (f"reset: stress moved {old:.2f} -> {stress:.2f} MPa, plant gain changed by "
                               f"{100 * (ratio - 1):+.0f} % (> learning.reset_gain_change)")
            return False              # this period straddled the change: learn from the next
        self.correction_um *= ratio
        return True

    # ---- state out ---------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        trend = [round(float(v), 4) for v in self.trend_rms_um if v == v][-10:]
        return {"enabled": True, "kind": "repetitive", "period_s": self.period_s, "samples_per_period": self.n,
                "periods": self.periods, "learned_periods": self.learned_periods,
                "frozen": bool(self.frozen_reason), "frozen_reason": self.frozen_reason or None,
                "frozen_since_s": self.frozen_since_s if self.frozen_reason else None,
                "rms_trend_um": trend, "correction_rms_um": float(np.sqrt(np.mean(self.correction_um ** 2))),
                "cutoff_hz": self.cutoff_hz, "last_event": self.last_event or None}

    def to_dict(self) -> dict[str, Any]:
        return {"format": "gma-ffc-learned-correction", "version": 1, "period_s": self.period_s,
                "rate_hz": self.rate_hz, "samples": self.n, "model_fingerprint": self.fingerprint,
                "stress_MPa": None if self.learned_stress_MPa != self.learned_stress_MPa else self.learned_stress_MPa,
                "learned_periods": self.learned_periods,
                "correction_um": [float(v) for v in self.correction_um]}

    def load_dict(self, d: Mapping[str, Any], source: str) -> None:
        """Take a saved buffer; refuse one learned for another period, rate or model."""
        if not isinstance(d, Mapping) or d.get("format") != "gma-ffc-learned-correction":
            raise ConfigError(f"{source}: not a learned-correction file (format: gma-ffc-learned-correction)")
        try:
            n, period, rate = int(d["samples"]), float(d["period_s"]), float(d["rate_hz"])
            values = np.asarray(d["correction_um"], dtype=float)
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"{source}: damaged learned-correction file ({exc}); delete it to start afresh") from None
        if n != self.n or abs(period - self.period_s) > 1e-9 * max(1.0, period) or rate != self.rate_hz:
            raise ConfigError(f"{source}: learned for a {period:g} s period at {rate:g} Hz ({n} samples), but this run "
                              f"has {self.period_s:g} s at {self.rate_hz:g} Hz ({self.n}); delete it to start afresh")
        if d.get("model_fingerprint") != self.fingerprint:
            raise ConfigError(f"{source}: learned with another model; a correction only fits the model it was "
                              f"learned through. Delete it to start afresh")
        if values.shape != (n,) or not np.all(np.isfinite(values)):
            raise ConfigError(f"{source}: correction_um must be {n} finite values")
        self.correction_um[:] = np.clip(values, -self.cfg.max_correction_um, self.cfg.max_correction_um)
        s = d.get("stress_MPa")
        self.learned_stress_MPa = float(s) if s is not None else math.nan
        self.last_event = f"loaded {source} ({d.get('learned_periods', '?')} periods learned)"


def model_gain_table(model: Model, n: int = 33) -> Callable[[float], float] | None:
    """Plant gain against stress from the model: the stroke of a full sweep of its drive range.

    Returns a function stress -> gain (interpolated in a table built once here, so the
    per-period call is cheap); None for a stress-independent model.
    """
    rng, drive = model.stress_range_MPa, model.drive_range
    if rng is None or not all(math.isfinite(v) for v in drive):
        return None
    lo, hi = float(rng[0]), float(rng[1])
    stresses = np.linspace(lo, hi, n)
    sweep = np.concatenate([np.linspace(drive[0], drive[1], 200), np.linspace(drive[1], drive[0], 200)])
    gains = np.empty(n)
    for i, s in enumerate(stresses):
        y = model.simulate(None, sweep, s)
        gains[i] = float(np.ptp(y)) / max(drive[1] - drive[0], 1e-300)
    xs, gs = stresses.tolist(), gains.tolist()

    def gain(stress: float) -> float:
        return float(np.interp(min(max(stress, lo), hi), xs, gs))

    return gain
