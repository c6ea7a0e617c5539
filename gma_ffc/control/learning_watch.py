"""Never worse than feedforward: the baseline the learner measures first, and the judgement of
each later window of periods against it (issue 32; derivation in docs/learning.md).

Pure arithmetic on per-period mean squares and on the error buffers the learner already holds:
no I/O, no clock, and no allocation after construction (it runs at period ends, in the tick).

The baseline is a few feedforward periods (no correction applied). From them:

* `B2`, the feedforward mean square error per period (their median);
* `nr2`, the non-repeatable error variance per sample: half the mean square of the difference
  of two consecutive periods, phase by phase (what repeats cancels, noise and jitter stay);
* `q2`, the part of `nr2` inside the robustness filter's band: the noise learning passes into
  the correction;
* `s`, the spread of one period's mean square: the larger of the spread seen across the
  baseline periods and what white noise of variance `nr2` alone would give.

Learning is judged period by period. Two things change the error that are not the learning:
the noise itself (a busier network, a loaded machine missing deadlines) and the noise learning
adds. Above the filter's band the learning does not act, so the non-repeatable error there
(`highpass_change`, period against period) measures the noise now; `rho` is its ratio to the
baseline's, at least 1. Feedforward would now have a mean square of `B2 + (rho - 1) nr2`. With
`extra` the noise learning adds (the correction's own variance in steady state,
`L^2 q2 / (1 - (f - L)^2)`; for f = 1 that is `L / (2 - L) * q2`), the excess of a period is

    z = (r2 - B2 - (rho - 1) nr2 - rho extra) / (rho s)

in units of the noise. `z > Z sqrt(1 + 1/P)` is one period worse than feedforward by more than
the noise: it is not learned from (a stall, a burst of late ticks, a knock on the rig: its error
is not the repeating one). The median of the last `W` periods' `z` beyond `Z sqrt(pi/(2W) + 1/P)`
(the variance of a median of W) means the learning itself made things worse, and the learner
backs off. A median, so that one bad period cannot force a back-off on its own; a divergence
grows below the band and leaves `rho` alone.
"""

from __future__ import annotations

import math

import numpy as np

from .learning_kernels import highpass_change, lowpass_circular, period_difference

WORSE_SIGMAS = 3.0      # Z: a false alarm about once in 700 windows when learning only matches feedforward
FINE, HOLD, BACK_OFF = 0, 1, 2     # verdicts on a learning period


class BaselineWatch:
    """The feedforward baseline (`add_baseline` until it returns True), then `worse(r2, ...)`
    once per learning period. `n` is the number of samples in a period."""

    def __init__(self, n: int, baseline_periods: int, window: int, filter_a: float, zero_phase: bool) -> None:
        self.n = n
        self.periods = baseline_periods
        self.window = window
        self._a = filter_a
        self._zero_phase = zero_phase
        self._r2 = np.zeros(baseline_periods)
        self._prev_err = np.zeros(n)
        self._prev_seen = np.zeros(n, dtype=np.bool_)
        self._diff = np.zeros(n)
        self._recent = np.zeros(window)      # the last W periods' excess z
        self._recent_r2 = np.zeros(window)   # and their mean squares (for the words)
        self._sorted = np.zeros(window)      # scratch for a median, sorted in place (no allocation)
        self._hp = np.zeros(n)
        self._prev_hp = np.zeros(n)
        self._prev_hp_seen = np.zeros(n, dtype=np.bool_)
        self._scratch = np.zeros(n)
        self.rho = 1.0
        self.reset()

    def reset(self) -> None:
        """Measure the baseline afresh (at start, and after the plant changed)."""
        self.count = 0
        self._pairs = 0
        self._nr2_sum = 0.0
        self._q2_sum = 0.0
        self._hf2_sum = 0.0
        self._hf_pairs = 0
        self.hf2 = math.nan                  # the baseline's non-repeatable error above the band
        self._prev_hp_seen[:] = False
        self.B2 = math.nan
        self.nr2 = math.nan
        self.q2 = math.nan
        self.s = math.nan
        self.restart_window()

    def restart_window(self) -> None:
        """Judge only periods from now on (after a back-off, or when learning starts)."""
        self._recent[:] = 0.0
        self._recent_r2[:] = 0.0
        self._filled = 0

    @property
    def done(self) -> bool:
        return self.count >= self.periods

    # ---- the baseline -------------------------------------------------------------------------
    def noise_change(self, err: np.ndarray, seen: np.ndarray) -> float:
        """The non-repeatable error variance above the band, this period against the last one
        used (NaN for the first). Call once for every period used, baseline or learning."""
        total, both = highpass_change(err, seen, self._a, self._zero_phase, self._hp, self._prev_hp,
                                      self._prev_hp_seen, self._scratch)
        return 0.5 * total / both if both else math.nan

    def add_baseline(self, err: np.ndarray, seen: np.ndarray, r2: float) -> bool:
        """One feedforward period's error by phase (`seen`: the phases observed) and its mean
        square. True when the baseline is complete."""
        hf2 = self.noise_change(err, seen)
        if hf2 == hf2:
            self._hf2_sum += hf2
            self._hf_pairs += 1
        if self.count:
            self._add_pair(err, seen)
        self._r2[self.count] = r2
        self.count += 1
        self._prev_err[:] = err
        self._prev_seen[:] = seen
        if self.done:
            self._finish()
        return self.done

    def _add_pair(self, err: np.ndarray, seen: np.ndarray) -> None:
        d = self._diff
        both = period_difference(err, seen, self._prev_err, self._prev_seen, d)
        if both == 0:
            return
        self._nr2_sum += 0.5 * float(np.dot(d, d)) / both
        if self._a < 1.0:
            lowpass_circular(d, self._a, self._zero_phase)
        self._q2_sum += 0.5 * float(np.dot(d, d)) / both
        self._pairs += 1

    def _finish(self) -> None:
        r2 = self._r2[:self.count]
        self.B2 = float(np.median(r2))       # a median: one baseline period with a stall does not set it
        self.nr2 = self._nr2_sum / self._pairs if self._pairs else 0.0
        self.q2 = self._q2_sum / self._pairs if self._pairs else 0.0
        self.hf2 = self._hf2_sum / self._hf_pairs if self._hf_pairs else 0.0
        # White noise of variance nr2 on a repeating error of mean square B2 - nr2 gives one
        # period's mean square a variance (4 (B2 - nr2) nr2 + 2 nr2^2) / n.
        white = (4.0 * max(self.B2 - self.nr2, 0.0) * self.nr2 + 2.0 * self.nr2 ** 2) / self.n
        seen_spread = float(r2.var(ddof=1)) if self.count > 1 else 0.0
        self.s = math.sqrt(max(white, seen_spread))

    # ---- judging learning ---------------------------------------------------------------------
    def _extra(self, gain: float, forgetting: float) -> float:
        return gain * gain * self.q2 / max(1.0 - (forgetting - gain) ** 2, 1e-12)

    def _limit(self, periods: int) -> float:
        """The excess z beyond which one period (`periods` 0) or the median of W is worse."""
        spread = math.pi / (2.0 * periods) if periods else 1.0
        return WORSE_SIGMAS * math.sqrt(spread + 1.0 / self.count)

    def threshold(self, gain: float, forgetting: float, periods: int = 0) -> float:
        """The mean square beyond which learning counts as worse than feedforward, at the noise
        seen last: for one period, or (`periods` = W) for the median of the window."""
        rho = self.rho
        return self.B2 + (rho - 1.0) * self.nr2 + rho * self._extra(gain, forgetting) + rho * self.s * self._limit(periods)

    def clearly_better(self, r2: float) -> bool:
        """One period's mean square below feedforward's by more than the noise (what may be saved)."""
        return self.done and r2 < self.B2 - self.s * self._limit(0)

    def judge(self, err: np.ndarray, seen: np.ndarray, r2: float, gain: float, forgetting: float) -> int:
        """FINE, HOLD (this period is beyond the noise band: do not learn from it) or BACK_OFF
        (the median of the last `window` periods is: the learning made things worse)."""
        hf2 = self.noise_change(err, seen)
        self.rho = max(1.0, hf2 / self.hf2) if self.hf2 > 0.0 and hf2 == hf2 else 1.0
        unit = max(self.rho * self.s, 1e-300)
        z = (r2 - self.B2 - (self.rho - 1.0) * self.nr2 - self.rho * self._extra(gain, forgetting)) / unit
        self._recent[:-1] = self._recent[1:]
        self._recent[-1] = z
        self._recent_r2[:-1] = self._recent_r2[1:]
        self._recent_r2[-1] = r2
        self._filled += 1
        if self._filled >= self.window and self._median(self._recent) > self._limit(self.window):
            return BACK_OFF
        return HOLD if z > self._limit(0) else FINE

    def _median(self, values: np.ndarray) -> float:
        x = self._sorted
        x[:] = values
        x.sort()
        m = self.window // 2
        return float(x[m]) if self.window % 2 else 0.5 * float(x[m - 1] + x[m])

    def window_rms(self) -> float:
        """RMS of the median period of the window."""
        return math.sqrt(self._median(self._recent_r2)) if self._filled >= self.window else math.nan
