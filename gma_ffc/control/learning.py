"""Learning feedforward: repetitive control on top of the inverse model (issues 12 and 32).

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

Limits (issue 32). Where a limit cut the command for phase j (current floor or ceiling, slew, the
model's range), the update at j may not push further into that limit (anti-windup, as ILC with
input constraints does); the rest of the period learns as usual. Phases a period did not observe
(missed ticks) are not updated. A period is not learned from at all only when the controller
says so (a fault of the fault table, stopping, no stress yet), during the ramp after a start or a
reconnect, and when the displacement reading is missing, stuck or absurd.

Never worse than feedforward. The first periods run the feedforward alone and measure its RMS and
noise (`learning_watch.BaselineWatch`). Every later window of periods is judged against that;
a worse one restores the best correction so far with half the gain, and after
`max_backoffs` learning stops. Only a correction measured better than feedforward is saved.

Hot-path contract: `correction()`, `limited()` and `observe()` allocate nothing and log nothing;
the period update runs in a compiled kernel on preallocated buffers. Events (a baseline, the
reference beyond the limits, a back-off, a reset) are kept for the status; the service logs
them. A change of the plant's gain with stress scales the buffer, and a large one resets it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np

from ..errors import ConfigError
from ..model_reach import full_range_sweep
from .learning_kernels import filter_coefficient, highpass_change, learn_period, lowpass_circular, period_difference
from .learning_watch import BACK_OFF, HOLD, BaselineWatch
from .safety import LIMITS, RAMP

_lowpass_circular = lowpass_circular     # the name the tests and earlier code know

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
    cutoff_hz: float | None = None      # Q's -3 dB point; None: cutoff_harmonics of the reference, at most rate/10
    cutoff_harmonics: float = 10.0      # phase margin for an uncovered delay up to ~1/(5 f0 * 10): docs/learning.md
    lead_samples: int = 0               # m: latency lead_s leaves uncovered (negative: lead_s covers too much)
    forgetting: float = 1.0             # f: < 1 lets an old correction fade when the error is gone
    max_correction_um: float = 5.0      # bound on |c|
    max_error_um: float = 50.0          # |r - y| beyond this is an absurd reading: freeze
    stale_ticks: int = 50               # an unchanged displacement reading this long: freeze
    reset_gain_change: float = 0.2      # relative plant-gain change (with stress) that resets c
    baseline_periods: int = 3           # feedforward periods measured before learning: 2 differences for the noise
    watch_periods: int = 3              # W: a back-off needs the median of W periods worse (one bad period cannot)
    max_backoffs: int = 3               # back-offs (gain halved each time) before learning stops
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
        number("cutoff_harmonics", 0.0, 1e4, lo_open=True)
        number("forgetting", 0.5, 1.0)
        number("max_correction_um", 0.0, 1e4, lo_open=True)
        number("max_error_um", 0.0, 1e6, lo_open=True)
        number("reset_gain_change", 0.0, 10.0, lo_open=True)
        for key, lo in (("lead_samples", -1_000_000), ("stale_ticks", 0), ("baseline_periods", 2),
                        ("watch_periods", 1), ("max_backoffs", 1)):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise bad(key, f"must be a whole number >= {lo}")
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


MIN_SEEN_SHARE = 0.5       # a period with fewer phases observed is a stall, not jitter: its RMS says little
EVENTS_KEPT = 20           # learning events kept for the status (the service logs each once)
MAX_SPANS = 6              # limited stretches of the period listed in the status, longest first
LIMIT_NAMES = ("none",) + LIMITS                           # by the code kept per phase
LIMIT_CODES = {name: code for code, name in enumerate(LIMIT_NAMES)}
LIMIT_CODES[""] = 0
RAMP_CODE = LIMIT_CODES[RAMP]
RAMPING = "command ramping to or from the safe current (a start, a reconnect, a stop): a transient"

# Stages of a learner's life (status "stage").
BASELINE = "baseline"          # measuring the feedforward alone, nothing applied
LEARNING = "learning"
HOLDING = "holding"            # stopped learning after too many back-offs: the best correction held
FEEDFORWARD = "feedforward"    # even the held correction turned worse: nothing applied any more


class RepetitiveLearner:
    """The learned correction of one period, indexed by phase; see the module docstring.

    Per tick the law that owns it (`law.FeedforwardController`) calls `correction(t + lead)` (for
    the command), then `limited(...)` when a limit cut that command, then `observe(t, ...)` with
    what the sensors saw; a fault that deactivates the law calls `freeze`.
    `gain_of_stress` maps a stress (MPa) to the plant's gain (um per unit of reference, from the
    model); it is evaluated once per period, never in a tick.
    """

    saved: dict[str, Any] | None = None     # the end of run's save, once made (`learned_file.save_if_learned`)

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
        self.correction_um = np.zeros(n)       # c: learned; applied once the baseline is measured
        self._best = np.zeros(n)               # the correction of the best period so far (what is saved)
        self._err = np.zeros(n)                # this period's error, by phase
        self._seen = np.zeros(n, dtype=np.bool_)
        self._ref = np.zeros(n)                # the reference, by phase (for the status's words)
        self._limit = np.zeros(n, dtype=np.int8)       # LIMIT_CODES of the latest command for each phase
        self._push = np.zeros(n, dtype=np.int8)        # sign of (limited - asked) there
        self._last_limit = np.zeros(n, dtype=np.int8)  # of the last complete period
        self._base_limit = np.zeros(n, dtype=np.int8)  # any limit met while measuring the baseline
        if 2 * abs(cfg.lead_samples) >= n:
            raise ConfigError(f"config key 'learning.lead_samples' is {cfg.lead_samples}, but a period has only {n} "
                              f"samples: a lead of half a period or more turns the learning's sign")
        cutoff = cfg.cutoff_hz if cfg.cutoff_hz is not None else min(cfg.cutoff_harmonics / period_s, rate_hz / 10.0)
        self.cutoff_hz = cutoff
        self._zero_phase = cfg.filter == "zero_phase"
        self._a = filter_coefficient(cutoff, rate_hz, self._zero_phase)
        self.watch = BaselineWatch(n, cfg.baseline_periods, cfg.watch_periods, self._a, self._zero_phase)
        self._gain_of_stress = gain_of_stress
        self.trend_rms_um = np.full(TREND, np.nan)
        self.trend_limited = np.full(TREND, np.nan)
        self.periods = 0                       # periods completed
        self.learned_periods = 0               # periods learned from
        self.stage = BASELINE
        self.gain = cfg.gain                   # halves at each back-off
        self.backoffs = 0
        self.held_periods = 0                  # periods beyond the noise band, not learned from
        self.best_r2 = math.nan                # mean square of the period `_best` was applied in
        self.best_period = 0
        self.reference_limits: list[dict[str, Any]] | None = None    # said once, when the baseline ends
        self._skip = 1                         # the first period is the start-up transient
        self._loaded = False
        self.frozen_reason = "waiting for the first full period"
        self.frozen_since_s = 0.0
        self.events: list[dict[str, Any]] = []
        self.event_count = 0
        self.learned_stress_MPa = math.nan
        self._cmd_phase = 0
        self._last_phase = -1
        self._period_clean = False
        self._sum_sq = 0.0
        self._count = 0
        self._stress_sum = 0.0
        self._last_y = math.nan
        self._same_y = 0
        self._last_command, self._frozen_tick = math.nan, False     # the last tick's command; frozen or not
        self.last_correction_um = 0.0
        warm_up_kernels()

    # ---- the tick (allocation-free) --------------------------------------------------------
    def phase(self, t: float) -> int:
        x = (t % self.period_s) / self.period_s * self.n
        k = int(x + 0.5)
        return k - self.n if k >= self.n else k

    def correction(self, t_target: float) -> float:
        """c for the instant the command is meant for (the controller's t + lead); nothing while
        the feedforward baseline is measured or after learning gave up."""
        k = self.phase(t_target)
        self._cmd_phase = k
        self._limit[k] = 0
        self._push[k] = 0
        c = self.correction_um[k] if self.stage == LEARNING or self.stage == HOLDING else 0.0
        self.last_correction_um = c
        return c

    def limited(self, t: float, limit: str, push: float) -> None:
        """The command asked for at the last `correction` was cut by `limit` (one of
        `safety.LIMITS`); `push` = limited - asked. Learning goes on elsewhere in the period; at
        this phase c may not grow towards the limit. A ramp to or from the safe current is a
        transient: the period teaches nothing."""
        k = self._cmd_phase
        self._limit[k] = LIMIT_CODES.get(limit, 0)
        self._push[k] = 1 if push > 0.0 else (-1 if push < 0.0 else 0)
        if limit == RAMP:
            self._freeze(t, RAMPING)

    def observe(self, t: float, reference_um: float, displacement_um: float, stress_MPa: float,
                ok: bool, why_not: str = "", command_A: float = math.nan) -> None:
        """Record e = r - y at run time t. `ok` False (with a reason) freezes learning this tick.
        A stuck sensor is a reading that stays put while the command moves: a command held at a
        limit (or a flat stretch of the reference) holds a noise-free displacement too, which froze
        learning as a stuck sensor on the simulated rig. Without `command_A`, every tick counts."""
        k = self.phase(t)
        if k < self._last_phase:
            self._end_period(t)
        self._last_phase = k
        y = displacement_um
        moved = command_A != self._last_command      # NaN (not given) always counts as moved
        self._last_command = command_A
        if y == self._last_y:
            self._same_y += moved
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
            self._frozen_tick = False
            self._err[k] = e
            self._ref[k] = reference_um
            self._seen[k] = True
            self._sum_sq += e * e
            self._count += 1
            self._stress_sum += stress_MPa
            return

    def freeze(self, t: float, reason: str) -> None:
        """Learn nothing from the current period (a fault, a reconnect, ...); keep c."""
        self._freeze(t, reason)

    def _freeze(self, t: float, reason: str) -> None:
        """This tick teaches nothing, for `reason`; `frozen_since_s` is when an unbroken run of such
        ticks (for one reason) began, across period ends (it restarted each period before)."""
        if not self._frozen_tick or self.frozen_reason != reason:
            self.frozen_since_s = t
        self.frozen_reason = reason
        self._frozen_tick = True
        self._period_clean = False

    # ---- once per period -------------------------------------------------------------------
    def _end_period(self, t: float) -> None:
        self.periods += 1
        r2 = self._sum_sq / self._count if self._count else math.nan
        self.trend_rms_um[:-1] = self.trend_rms_um[1:]
        self.trend_rms_um[-1] = math.sqrt(r2)
        self._last_limit[:] = self._limit
        self.trend_limited[:-1] = self.trend_limited[1:]
        self.trend_limited[-1] = np.count_nonzero(self._limit) / self.n
        if self._skip:                # the first period: partial, or the start-up transient
            self._skip -= 1
        elif self._period_clean and self._count >= MIN_SEEN_SHARE * self.n:
            self.frozen_reason = ""
            self._use_period(t, r2)
        elif self._period_clean:
            self._freeze(t, f"only {self._count} of {self.n} phases observed (missed ticks)")
        self._seen[:] = False
        self._sum_sq = 0.0
        self._count = 0
        self._stress_sum = 0.0
        self._period_clean = True     # until a tick of the new period says otherwise

    def _use_period(self, t: float, r2: float) -> None:
        """A clean period: part of the baseline, or judged against it and learned from."""
        if not self._stress_rule(t, self._stress_sum / self._count):
            return
        if self.stage == BASELINE:
            np.maximum(self._base_limit, self._limit, out=self._base_limit)
            if self.watch.add_baseline(self._err, self._seen, r2):
                self._start_learning(t)
            return
        if self.stage == FEEDFORWARD:
            return
        verdict = self.watch.judge(self._err, self._seen, r2, self.gain, self.cfg.forgetting)
        if verdict == BACK_OFF:
            self._back_off(t)
            return
        if r2 < self.best_r2:
            self._best[:] = self.correction_um          # the correction this period ran with
            self.best_r2 = r2
            self.best_period = self.periods
        if verdict == HOLD:
            self.held_periods += 1                      # a stall or a knock: not the repeating error
        elif self.stage == LEARNING:
            self._learn()

    def _learn(self) -> None:
        learn_period(self.correction_um, self._err, self._seen, self._push, self.gain, self.cfg.forgetting,
                     self.cfg.lead_samples, self._a, self._zero_phase, self.cfg.max_correction_um)
        self.learned_periods += 1

    def _start_learning(self, t: float) -> None:
        w = self.watch
        self.stage = LEARNING
        self.best_r2 = w.B2                         # feedforward: the correction to beat is none
        self._best[:] = 0.0
        self.best_period = self.periods
        first, last = self.periods - w.count + 1, self.periods
        self.note(t, f"feedforward baseline {math.sqrt(w.B2):.4g} um RMS (periods {first}-{last}; non-repeatable "
                     f"{math.sqrt(w.nr2):.3g} um); learning {'applies the loaded correction' if self._loaded else 'starts'}")
        np.copyto(self._base_limit, 0, where=self._base_limit == RAMP_CODE)
        if np.any(self._base_limit):
            self.reference_limits = limit_spans(self._base_limit, self._ref)
            share = np.count_nonzero(self._base_limit) / self.n
            where = "; ".join(f"phase {s['from']:.2f}-{s['to']:.2f} ({s['limit']}, reference "
                              f"{s['reference_um'][0]:.3g}-{s['reference_um'][1]:.3g} um)" for s in self.reference_limits)
            self.note(t, f"the reference asks for more than the rig's limits on {100 * share:.1f} % of each period "
                         f"without learning: {where}. The rig cannot follow it there; learning leaves those "
                         f"phases alone and learns the rest")
        else:
            self.reference_limits = []
        w.restart_window()
        if not self._loaded:                        # the baseline's last error is the first lesson
            self._learn()

    def _back_off(self, t: float) -> None:
        """A window of periods was worse than feedforward: back to the best correction, with
        half the gain; the last allowed back-off stops learning, holding that correction."""
        w = self.watch
        self.backoffs += 1
        why = (f"periods {self.periods - w.window + 1}-{self.periods}: median {w.window_rms():.3g} um RMS, worse "
               f"than feedforward {math.sqrt(w.B2):.3g} um by more than the noise (limit "
               f"{math.sqrt(w.threshold(self.gain, self.cfg.forgetting, w.window)):.3g} um)")
        best = "feedforward alone" if self.best_r2 >= w.B2 else \
            f"the correction of period {self.best_period} ({math.sqrt(self.best_r2):.3g} um)"
        if self.stage == HOLDING:
            self.correction_um[:] = 0.0
            self._best[:] = 0.0
            self.best_r2 = w.B2
            self.stage = FEEDFORWARD
            self.note(t, f"{why}: even the held correction is worse now; feedforward alone from here")
        elif self.backoffs >= self.cfg.max_backoffs:
            self.correction_um[:] = self._best
            self.stage = HOLDING
            self.note(t, f"{why}: back-off {self.backoffs} of {self.cfg.max_backoffs}, learning stopped; holding "
                         f"{best}. The plant does not behave as the learning assumes (docs/learning.md)")
        else:
            self.correction_um[:] = self._best
            old, self.gain = self.gain, 0.5 * self.gain
            self.note(t, f"{why}: backed off to {best}, gain {old:g} -> {self.gain:g}")
        w.restart_window()

    def _stress_rule(self, t: float, stress: float) -> bool:
        """Scale c by the plant's gain change since it was learned; reset it past
        `reset_gain_change` (the learned shape belongs to another plant, and so does the baseline).
        True: use this period."""
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
            self._best[:] = 0.0
            self._loaded = False
            if self.stage != BASELINE:
                self.stage = BASELINE if self.stage == LEARNING else FEEDFORWARD
                self.watch.reset()
                self._base_limit[:] = 0
            self.note(t, f"reset: stress moved {old:.2f} -> {stress:.2f} MPa, plant gain changed by "
                         f"{100 * (ratio - 1):+.0f} % (> learning.reset_gain_change); "
                         + ("measuring the feedforward baseline again" if self.stage == BASELINE else
                            "feedforward alone (learning had stopped)"))
            return False              # this period straddled the change: learn from the next
        self.correction_um *= ratio
        self._best *= ratio
        return True

    # ---- events and state out ----------------------------------------------------------------
    def note(self, t: float, text: str) -> None:
        """Record an event (rare: a baseline, a back-off, a reset); the service logs each once."""
        self.event_count += 1
        self.events.append({"seq": self.event_count, "t_s": round(float(t), 3) if t == t else None, "text": text})
        del self.events[:-EVENTS_KEPT]

    @property
    def last_event(self) -> str:
        return self.events[-1]["text"] if self.events else ""

    @last_event.setter
    def last_event(self, text: str) -> None:
        self.note(math.nan, text)

    @property
    def saveable(self) -> bool:
        """True when some correction was measured better than feedforward by more than the
        noise (the best one is what is saved)."""
        return self.stage != BASELINE and self.watch.clearly_better(self.best_r2)

    def status(self) -> dict[str, Any]:
        w = self.watch
        trend = [round(float(v), 4) for v in self.trend_rms_um if v == v][-10:]
        limited = self._last_limit
        share = {LIMIT_NAMES[code]: round(float(np.count_nonzero(limited == code)) / self.n, 4)
                 for code in np.unique(limited) if code}
        measured = w.done
        return {"enabled": True, "kind": "repetitive", "stage": self.stage, "period_s": self.period_s,
                "samples_per_period": self.n, "periods": self.periods, "learned_periods": self.learned_periods,
                "frozen": bool(self.frozen_reason), "frozen_reason": self.frozen_reason or None,
                "frozen_since_s": self.frozen_since_s if self.frozen_reason else None,
                "rms_trend_um": trend, "correction_rms_um": float(np.sqrt(np.mean(self.correction_um ** 2))),
                "cutoff_hz": self.cutoff_hz, "gain": self.gain, "backoffs": self.backoffs,
                "held_periods": self.held_periods,
                "baseline_rms_um": _root(w.B2) if measured else None,
                "nonrepeatable_um": _root(w.nr2) if measured else None,
                "worse_above_um": _root(w.threshold(self.gain, self.cfg.forgetting)) if measured else None,
                "noise_ratio": round(w.rho, 3) if measured else None,
                "best_rms_um": _root(self.best_r2) if measured else None,
                "limited": {"share": round(float(np.count_nonzero(limited)) / self.n, 4), "by": share,
                            "where": limit_spans(limited, self._ref)},
                "limited_share_trend": [round(float(v), 4) for v in self.trend_limited if v == v][-10:],
                "reference_beyond_limits": self.reference_limits,
                "last_event": self.last_event or None, "events": list(self.events), "saved": self.saved}

    def to_dict(self) -> dict[str, Any]:
        """The best correction measured (never one that was worse than feedforward)."""
        w = self.watch
        return {"format": "gma-ffc-learned-correction", "version": 2, "period_s": self.period_s,
                "rate_hz": self.rate_hz, "samples": self.n, "model_fingerprint": self.fingerprint,
                "stress_MPa": None if self.learned_stress_MPa != self.learned_stress_MPa else self.learned_stress_MPa,
                "learned_periods": self.learned_periods,
                "baseline_rms_um": _root(w.B2), "rms_um": _root(self.best_r2),
                "correction_um": [float(v) for v in self._best]}

    def load_dict(self, d: Mapping[str, Any], source: str) -> None:
        """Take a saved buffer; refuse one learned for another period, rate or model. It is
        applied after this run's own feedforward baseline, and judged against it."""
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
        self._loaded = True
        s = d.get("stress_MPa")
        self.learned_stress_MPa = float(s) if s is not None else math.nan
        self.note(math.nan, f"loaded {source} ({d.get('learned_periods', '?')} periods learned); applied after "
                            f"the feedforward baseline")


def _root(x: float) -> float | None:
    return round(math.sqrt(x), 5) if x == x and x >= 0.0 else None


def limit_spans(codes: np.ndarray, reference_um: np.ndarray) -> list[dict[str, Any]]:
    """The stretches of the period where a limit cut the command: phase from-to (fractions of the
    period, circular), the limit, its share of the period, and the reference there. Longest first.
    Vectorised: it may run at a period's end, inside a tick."""
    n = codes.shape[0]
    limited = codes != 0
    if not limited.any():
        return []
    start = int(np.argmin(limited)) if not limited.all() else 0     # begin at an unlimited phase
    rolled = np.roll(codes, -start)
    edges = np.concatenate(([0], np.flatnonzero(np.diff(rolled)) + 1, [n]))
    runs = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if rolled[a]]
    runs.sort(key=lambda r: r[0] - r[1])
    out = []
    for a, b in runs[:MAX_SPANS]:
        idx = (start + np.arange(a, b)) % n
        first = (start + a) % n
        out.append({"from": round(first / n, 3), "to": round((first + b - a) / n % 1.0 or 1.0, 3),
                    "limit": LIMIT_NAMES[int(rolled[a])], "share": round((b - a) / n, 4),
                    "reference_um": [round(float(reference_um[idx].min()), 3), round(float(reference_um[idx].max()), 3)]})
    return out


def warm_up_kernels() -> None:
    """Compile (or load from the cache) the period kernels now, not at the first period's end."""
    c, e, push = np.zeros(8), np.ones(8), np.zeros(8, dtype=np.int8)
    seen = np.ones(8, dtype=np.bool_)
    learn_period(c, e, seen, push, 0.5, 1.0, 0, 0.5, True, 1.0)
    period_difference(e, seen, c, seen, np.zeros(8))
    lowpass_circular(c, 0.5, True)
    highpass_change(e, seen, 0.5, True, np.zeros(8), np.zeros(8), seen.copy(), np.zeros(8))


def model_gain_table(model: Model, n: int = 33) -> Callable[[float], float] | None:
    """Plant gain against stress from the model: the stroke of a full sweep of its drive range.

    Returns a function stress -> gain (interpolated in a table built once here, so the
    per-period call is cheap); None for a stress-independent model.
    """
    rng, drive = model.stress_range_MPa, full_range_sweep(model)
    if rng is None or drive is None:
        return None
    lo, hi = float(rng[0]), float(rng[1])
    stresses = np.linspace(lo, hi, n)
    span = max(float(np.ptp(drive[1])), 1e-300)
    gains = np.empty(n)
    for i, s in enumerate(stresses):
        gains[i] = float(np.ptp(model.simulate(*drive, s))) / span
    xs, gs = stresses.tolist(), gains.tolist()

    def gain(stress: float) -> float:
        return float(np.interp(min(max(stress, lo), hi), xs, gs))

    return gain
