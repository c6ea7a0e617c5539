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

Learning is judged period by period. With `extra` the noise learning itself adds (the
correction's own variance in steady state, `L^2 q2 / (1 - (f - L)^2)`; for f = 1 that is
`L / (2 - L) * q2`), a mean square beyond

    B2 + extra + Z * s * sqrt(v + 1/P)

is worse than feedforward by more than the noise (`v` the variance factor of what is compared:
1 for one period, pi / (2 W) for the median of W). One such period is not learned from (a stall,
a burst of late ticks, a knock on the rig: its error is not the repeating one); the median of
the last `W` periods beyond its own limit means the learning itself made things worse, and the
learner backs off. A median, so that one bad period cannot force a back-off on its own.
"""

from __future__ import annotations

import math

import numpy as np

from .learning_kernels import lowpass_circular, period_difference

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
        self._recent = np.zeros(window)
        self._sorted = np.zeros(window)      # scratch for the median, sorted in place (no allocation)
        self.reset()

    def reset(self) -> None:
        """Measure the baseline afresh (at start, and after the plant changed)."""
        self.count = 0
        self._pairs = 0
        self._nr2_sum = 0.0
        self._q2_sum = 0.0
        self.B2 = math.nan
        self.nr2 = math.nan
        self.q2 = math.nan
        self.s = math.nan
        self.restart_window()

    def restart_window(self) -> None:
        """Judge only periods from now on (after a back-off, or when learning starts)."""
        self._recent[:] = 0.0
        self._filled = 0

    @property
    def done(self) -> bool:
        return self.count >= self.periods

    # ---- the baseline -------------------------------------------------------------------------
    def add_baseline(self, err: np.ndarray, seen: np.ndarray, r2: float) -> bool:
        """One feedforward period's error by phase (`seen`: the phases observed) and its mean
        square. True when the baseline is complete."""
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
        # White noise of variance nr2 on a repeating error of mean square B2 - nr2 gives one
        # period's mean square a variance (4 (B2 - nr2) nr2 + 2 nr2^2) / n.
        white = (4.0 * max(self.B2 - self.nr2, 0.0) * self.nr2 + 2.0 * self.nr2 ** 2) / self.n
        seen_spread = float(r2.var(ddof=1)) if self.count > 1 else 0.0
        self.s = math.sqrt(max(white, seen_spread))

    # ---- judging learning ---------------------------------------------------------------------
    def threshold(self, gain: float, forgetting: float, periods: int = 0) -> float:
        """The mean square beyond which learning counts as worse than feedforward: for one
        period, or (`periods` = W) for the median of the window."""
        extra = gain * gain * self.q2 / max(1.0 - (forgetting - gain) ** 2, 1e-12)
        spread = math.pi / (2.0 * periods) if periods else 1.0
        return self.B2 + extra + WORSE_SIGMAS * self.s * math.sqrt(spread + 1.0 / self.count)

    def clearly_better(self, r2: float) -> bool:
        """One period's mean square below feedforward's by more than the noise (what may be saved)."""
        return self.done and r2 < self.B2 - WORSE_SIGMAS * self.s * math.sqrt(1.0 + 1.0 / self.count)

    def judge(self, r2: float, gain: float, forgetting: float) -> int:
        """FINE, HOLD (this period is beyond the noise band: do not learn from it) or BACK_OFF
        (the median of the last `window` periods is: the learning made things worse)."""
        self._recent[:-1] = self._recent[1:]
        self._recent[-1] = r2
        self._filled += 1
        if self._filled >= self.window and self._median() > self.threshold(gain, forgetting, self.window):
            return BACK_OFF
        return HOLD if r2 > self.threshold(gain, forgetting) else FINE

    def _median(self) -> float:
        x = self._sorted
        x[:] = self._recent
        x.sort()
        m = self.window // 2
        return float(x[m]) if self.window % 2 else 0.5 * float(x[m - 1] + x[m])

    def window_rms(self) -> float:
        """RMS of the median period of the window."""
        return math.sqrt(self._median()) if self._filled >= self.window else math.nan
