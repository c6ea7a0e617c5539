"""The model-fit monitor: is the running model still the actuator's? (issue 30, docs/monitor.md)

Each tick the loop hands it the residual (measured minus predicted displacement), the drive it
wrote and the tracking error. The monitor keeps the residual's RMS over the last `window_s` of
valid ticks and compares it with what a model that still fits would leave:

    expected^2 = identification_error^2 + noise_floor^2

* the identification error is the model's own fit error on its identification recordings (the
  model file's provenance, `fit_rms_um`);
* the noise floor is estimated from the residual itself, from its second differences: white
  noise of deviation s gives second differences of deviation s*sqrt(6), while a model error
  that moves with the drive (a few Hz against a sampling of 100 Hz or more) hardly shows in them.

The ratio RMS / expected decides the state: `unknown` until a whole window of valid ticks is in,
then `ok` or `drifting` (`off` when the rig has no displacement channel). A drift never becomes a
fault here: the monitor only says so; what follows is the service's choice (`monitor.on_drift`).

Where the residual sits is kept per drive band and per drive-rate band over the last complete
window, so the status can say "largest at 2.2-2.6 A, at 9-28 A/s".

Hot path: `update` and `skip` do a handful of float operations on preallocated lists; they
allocate no containers and do no I/O. Everything else (`status`) runs off the loop.
"""

from __future__ import annotations

import math
from array import array
from typing import Any

OK, DRIFTING, OFF, UNKNOWN = "ok", "drifting", "off", "unknown"
STATES = (OK, DRIFTING, OFF, UNKNOWN)

# A drift is a residual this many times what a fitting model leaves. The model's errors on its own
# identification recordings differ by about 10 % from one recording to the next, and running it
# at other rates, amplitudes and stresses than those it was identified on costs it up to about
# 2x (scripts/monitor_survey.py, nothing missing: the largest ratio it measured is quoted in
# docs/monitor.md); 3x keeps clear of both, while the effects the diagnosis names reach 5-20x.
DRIFT_RATIO = 3.0
# Back to ok only below this: a band between the two thresholds, so a residual that hovers near
# the threshold does not flap between states (and start a diagnosis on every crossing).
CLEAR_RATIO = 2.0
DRIVE_BANDS = 8                  # equal bands over the model's identified drive range
# Drive-rate bands: |du/dt| in drive spans per second, half a decade apart from 0.03 to 30. A 3 Hz
# sine over the whole span peaks at ~9.4 spans/s; quasi-static identification sweeps stay below 1.
RATE_EDGES = tuple(0.03 * 10.0 ** (k / 2.0) for k in range(7))
_LOG_RATE_STEP = math.log(10.0) / 2.0


def identification_error_um(model: Any) -> float | None:
    """The model's own RMS fit error on its identification recordings (provenance `fit_rms_um`,
    which `gma-ffc identify` writes; an extended model's from its base), their quadratic mean;
    None when the file does not record one."""
    for candidate in (model, getattr(model, "base", None)):
        prov = getattr(candidate, "provenance", None)
        fits = prov.get("fit_rms_um") if isinstance(prov, dict) else None
        if isinstance(fits, dict):
            values = [float(v) for v in fits.values() if isinstance(v, (int, float)) and math.isfinite(v) and v >= 0]
            if values:
                return math.sqrt(sum(v * v for v in values) / len(values))
    return None


class FitMonitor:
    """Windowed residual RMS against the identification error and the noise floor; see the module doc.

    `window_n` valid ticks make a window. `ident_rms_um` None: the first whole window after start
    becomes the reference (said so in the status). `drive_range` sets the drive bands.
    """

    __slots__ = ("window_n", "period_s", "ident_rms_um", "lo", "band_scale", "rate_scale", "state", "since_t",
                 "ring", "i", "filled", "sum_window", "sum_pass", "d2_pass", "d2_n_pass", "tracking_pass",
                 "tracking_n_pass", "prev1", "prev2", "chain", "prev_drive", "band_sq", "band_n", "rate_sq", "rate_n",
                 "pub_band_sq", "pub_band_n", "pub_rate_sq", "pub_rate_n", "pub_tracking_sq", "published",
                 "ref_sq", "noise_sq", "last_t", "ratio_sq", "reference_words")

    def __init__(self, window_n: int, period_s: float, ident_rms_um: float | None,
                 drive_range: tuple[float, float] = (0.0, 1.0)) -> None:
        if window_n < 16:
            raise ValueError(f"a window needs at least 16 ticks, got {window_n}")
        self.window_n = int(window_n)
        self.period_s = float(period_s)
        self.ident_rms_um = ident_rms_um
        lo, hi = (float(v) for v in drive_range)
        span = hi - lo if math.isfinite(hi - lo) and hi > lo else 1.0
        self.lo = lo if math.isfinite(lo) else 0.0
        self.band_scale = DRIVE_BANDS / span
        self.rate_scale = 1.0 / (span * period_s * RATE_EDGES[0])    # |du| per tick -> multiples of the first edge
        self.ring = array("d", bytes(8 * self.window_n))     # raw doubles: no float object kept per sample
        # the bands of the window being filled, and of the last whole one (swapped at each wrap)
        self.band_sq, self.pub_band_sq = [0.0] * DRIVE_BANDS, [0.0] * DRIVE_BANDS
        self.band_n, self.pub_band_n = [0] * DRIVE_BANDS, [0] * DRIVE_BANDS
        self.rate_sq, self.pub_rate_sq = [0.0] * (len(RATE_EDGES) + 1), [0.0] * (len(RATE_EDGES) + 1)
        self.rate_n, self.pub_rate_n = [0] * (len(RATE_EDGES) + 1), [0] * (len(RATE_EDGES) + 1)
        self.reference_words = "the model's identification error (its file's provenance)" if ident_rms_um is not None \
            else "the first whole window after start (the model file records no identification error)"
        self.ref_sq = math.nan if ident_rms_um is None else ident_rms_um * ident_rms_um
        self.reset()

    def reset(self) -> None:
        """Forget every sample: a new model, or a new run, starts `unknown`."""
        self.state = UNKNOWN
        self.since_t = math.nan
        self.last_t = math.nan
        self.i = 0
        self.filled = 0
        self.sum_window = self.sum_pass = self.d2_pass = self.tracking_pass = 0.0
        self.d2_n_pass = self.tracking_n_pass = 0
        self.prev1 = self.prev2 = self.prev_drive = 0.0
        self.chain = 0
        self.noise_sq = math.nan
        self.ratio_sq = math.nan
        if self.ident_rms_um is None:
            self.ref_sq = math.nan
        self.pub_tracking_sq = math.nan
        self.published = False
        for k in range(self.window_n):
            self.ring[k] = 0.0
        self._clear_bands()

    def _clear_bands(self) -> None:
        for k in range(DRIVE_BANDS):
            self.band_sq[k] = 0.0
            self.band_n[k] = 0
        for k in range(len(self.rate_sq)):
            self.rate_sq[k] = 0.0
            self.rate_n[k] = 0

    # ---- hot path ------------------------------------------------------------------------------
    def skip(self) -> None:
        """A tick without a valid residual (no displacement, no prediction, not running)."""
        self.chain = 0

    def update(self, t: float, residual_um: float, drive: float, tracking_um: float) -> None:
        """One valid tick: the residual, the drive written and the tracking error (all finite)."""
        q = residual_um * residual_um
        i = self.i
        self.sum_window += q - self.ring[i]
        self.ring[i] = q
        self.sum_pass += q
        chain = self.chain
        if chain >= 2:
            d2 = residual_um - 2.0 * self.prev1 + self.prev2
            self.d2_pass += d2 * d2
            self.d2_n_pass += 1
        if chain >= 1:
            rate = abs(drive - self.prev_drive) * self.rate_scale
            r = 0 if rate < 1.0 else min(int(math.log(rate) / _LOG_RATE_STEP) + 1, len(RATE_EDGES))
            self.rate_sq[r] += q
            self.rate_n[r] += 1
        self.chain = chain + 1
        self.prev2 = self.prev1
        self.prev1 = residual_um
        self.prev_drive = drive
        b = int((drive - self.lo) * self.band_scale)
        b = 0 if b < 0 else (DRIVE_BANDS - 1 if b >= DRIVE_BANDS else b)
        self.band_sq[b] += q
        self.band_n[b] += 1
        self.tracking_pass += tracking_um * tracking_um
        self.tracking_n_pass += 1
        self.last_t = t
        i += 1
        if self.filled < self.window_n:
            self.filled += 1
        if i == self.window_n:
            i = 0
            self._wrap()
        self.i = i
        if self.filled == self.window_n:
            self._judge(t)

    def _wrap(self) -> None:
        """A whole window has passed: its exact sums replace the running ones (no rounding drift),
        and its noise floor, bands and tracking error are published for the status (the band lists
        are swapped, not copied: nothing is allocated)."""
        self.sum_window = self.sum_pass
        self.noise_sq = self.d2_pass / (6.0 * self.d2_n_pass) if self.d2_n_pass else 0.0
        if self.ref_sq != self.ref_sq:           # no identification error on file: this window is the reference
            self.ref_sq = self.sum_pass / self.window_n
        self.band_sq, self.pub_band_sq = self.pub_band_sq, self.band_sq
        self.band_n, self.pub_band_n = self.pub_band_n, self.band_n
        self.rate_sq, self.pub_rate_sq = self.pub_rate_sq, self.rate_sq
        self.rate_n, self.pub_rate_n = self.pub_rate_n, self.rate_n
        self.pub_tracking_sq = self.tracking_pass / self.tracking_n_pass if self.tracking_n_pass else math.nan
        self.published = True
        self.sum_pass = self.d2_pass = self.tracking_pass = 0.0
        self.d2_n_pass = self.tracking_n_pass = 0
        self._clear_bands()

    def _judge(self, t: float) -> None:
        expected = self.ref_sq + self.noise_sq
        ratio_sq = self.sum_window / self.window_n / expected if expected > 0.0 else math.inf
        self.ratio_sq = ratio_sq
        state = self.state
        if state == DRIFTING:
            if ratio_sq < CLEAR_RATIO * CLEAR_RATIO:
                self.state = OK
                self.since_t = t
        elif ratio_sq > DRIFT_RATIO * DRIFT_RATIO:
            self.state = DRIFTING
            self.since_t = t
        elif state == UNKNOWN:
            self.state = OK
            self.since_t = t

    # ---- reporting (off the hot path) ------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """The state, the ratio and its parts, since when, and where the residual sits."""
        n = self.filled
        rms = math.sqrt(max(self.sum_window, 0.0) / n) if n else math.nan
        noise = math.sqrt(self.noise_sq) if self.noise_sq == self.noise_sq else math.nan
        ref = math.sqrt(self.ref_sq) if self.ref_sq == self.ref_sq else math.nan
        return {
            "state": self.state,
            "since_s": _finite(self.since_t),
            "ratio": _finite(math.sqrt(self.ratio_sq)) if self.ratio_sq == self.ratio_sq else None,
            "residual_rms_um": _finite(rms),
            "identification_rms_um": _finite(ref),
            "noise_floor_um": _finite(noise),
            "reference": self.reference_words,
            "thresholds": {"drifting_above": DRIFT_RATIO, "ok_below": CLEAR_RATIO},
            "window": {"ticks": n, "of": self.window_n, "seconds": n * self.period_s,
                       "window_s": self.window_n * self.period_s},
            "tracking_rms_um": _finite(math.sqrt(self.pub_tracking_sq)) if self.published else None,
            "where": self.where(),
        }

    def where(self) -> dict[str, Any] | None:
        """The drive band and the drive-rate band with the largest residual RMS over the last whole
        window (bands holding under 2 % of its ticks are too few to speak for), or None before one."""
        if not self.published:
            return None
        span = DRIVE_BANDS / self.band_scale
        bands = [(self.lo + k * span / DRIVE_BANDS, self.lo + (k + 1) * span / DRIVE_BANDS) for k in range(DRIVE_BANDS)]
        rate_unit = span                                  # edges are in drive spans per second
        edges = (0.0,) + tuple(e * rate_unit for e in RATE_EDGES) + (math.inf,)
        rates = [(edges[k], edges[k + 1]) for k in range(len(edges) - 1)]
        return {"drive": _largest(bands, list(self.pub_band_sq), list(self.pub_band_n)),
                "drive_rate_per_s": _largest(rates, list(self.pub_rate_sq), list(self.pub_rate_n))}


def _largest(ranges: list[tuple[float, float]], sq: list[float], n: list[int]) -> dict[str, Any] | None:
    total = sum(n)
    rows = [(math.sqrt(s / c), r, c) for s, c, r in zip(sq, n, ranges) if c >= 0.02 * total and c > 0]
    if not rows:
        return None
    rms, (lo, hi), count = max(rows)
    return {"range": [_finite(lo), _finite(hi)], "rms_um": rms, "share": count / total,
            "bands": [{"range": [_finite(a), _finite(b)], "rms_um": math.sqrt(s / c) if c else None, "share": c / total}
                      for s, c, (a, b) in zip(sq, n, ranges)]}


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None
