"""The model-fit monitor: is the running model still the actuator's? (issue 30, docs/monitor.md)

It is fed the ticks since its last call, in blocks (`feed`), off the loop: the residual (measured
minus predicted displacement, NaN on ticks that are not judged), the drive the residual answers,
and the tracking error. It keeps the residual's RMS over the last `window_n` judged ticks and
compares it with what a model that still fits would leave:

    expected^2 = identification_error^2 + noise_floor^2

* the identification error is the model's own fit error on its identification recordings (the
  model file's provenance, `fit_rms_um`);
* the noise floor is estimated from the residual itself, from its second differences: white
  noise of deviation s gives second differences of deviation s*sqrt(6), while a model error
  that moves with the drive (a few Hz against a sampling of 100 Hz or more) hardly shows in them.

The ratio RMS / expected decides the state: `unknown` until a whole window of judged ticks is in,
then `ok` or `drifting` (`off` when the rig has no displacement channel). A drift never becomes a
fault here: the monitor only says so; what follows is the service's choice (`monitor.on_drift`).
Where the residual sits is kept per drive band and per drive-rate band.

The window is made of whole blocks (one per call, a few hundred ticks), so it spans between
`window_n` and `window_n` plus one block of judged ticks; a state changes at a block's last tick.
Why blocks: per tick the loop only predicts and stores the row (`model_watch`); the statistics,
a few vectorised operations over the new rows, cost the loop nothing and hold the interpreter
lock for microseconds at a time.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

OK, DRIFTING, OFF, UNKNOWN = "ok", "drifting", "off", "unknown"
STATES = (OK, DRIFTING, OFF, UNKNOWN)

# A drift is a residual this many times what a fitting model leaves. With nothing missing the ratio
# is 1.1-1.2 over most of the identified stroke at 1-10 Hz and -11 to -22 MPa, 2.3-2.8 over half of
# it (scripts/monitor_survey.py, docs/monitor.md); heating, creep and a 2 ms delay reach 6-10 at
# full stroke. 3x sits between. Small loops inside the stroke reach 4-5 with nothing missing (the
# model class fits them worse than its identification loops): the monitor says so from the first
# window on (`from_start`), which may be those conditions or a change that began before the first
# window was full (a coil heating from the start): the status says either may be.
DRIFT_RATIO = 3.0
# Back to ok only below this: a band between the two thresholds, so a residual that hovers near
# the threshold does not flap between states (and start a diagnosis on every crossing).
CLEAR_RATIO = 2.0
DRIVE_BANDS = 8                  # equal bands over the model's identified drive range
# Drive-rate bands: |du/dt| in drive spans per second, half a decade apart from 0.03 to 30. A 3 Hz
# sine over the whole span peaks at ~9.4 spans/s; quasi-static identification sweeps stay below 1.
RATE_EDGES = tuple(0.03 * 10.0 ** (k / 2.0) for k in range(7))
MIN_BAND_SHARE = 0.02            # a band holding fewer of the window's ticks is too thin to speak for


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


@dataclass
class Block:
    """The sums of one fed block of ticks."""

    n: int
    sq: float
    d2_sq: float
    d2_n: int
    band_sq: np.ndarray
    band_n: np.ndarray
    rate_sq: np.ndarray
    rate_n: np.ndarray
    tracking_sq: float


class FitMonitor:
    """Windowed residual RMS against the identification error and the noise floor; see the module doc.

    `window_n` judged ticks make a window. `ident_rms_um` None: the first whole window becomes the
    reference (said so in the status). `drive_range` sets the drive bands, `period_s` the rates.
    """

    def __init__(self, window_n: int, period_s: float, ident_rms_um: float | None,
                 drive_range: tuple[float, float] = (0.0, 1.0)) -> None:
        if window_n < 16:
            raise ValueError(f"a window needs at least 16 ticks, got {window_n}")
        self.window_n = int(window_n)
        self.period_s = float(period_s)
        self.ident_rms_um = ident_rms_um
        lo, hi = (float(v) for v in drive_range)
        self.span = hi - lo if math.isfinite(hi - lo) and hi > lo else 1.0
        self.lo = lo if math.isfinite(lo) else 0.0
        self.rate_edges = np.array(RATE_EDGES) * self.span          # drive units per second
        self.reference_words = "the model's identification error (its file's provenance)" if ident_rms_um is not None \
            else "the first whole window (the model file records no identification error)"
        self.reset()

    def reset(self) -> None:
        """Forget every tick: a new model starts `unknown`."""
        self.state = UNKNOWN
        self.since_t = math.nan
        self.from_start = False      # drifting at the first judgement: the conditions, not a change
        self.last_t = math.nan
        self.ratio = math.nan
        self.ref_sq = math.nan if self.ident_rms_um is None else self.ident_rms_um ** 2
        self.blocks: collections.deque[Block] = collections.deque()
        self.total = self._empty()
        self.tail_residual = np.full(2, np.nan)      # the last two residuals and drive, for the next block's
        self.tail_drive = math.nan                   # second differences and rates

    @staticmethod
    def _empty() -> Block:
        return Block(0, 0.0, 0.0, 0, np.zeros(DRIVE_BANDS), np.zeros(DRIVE_BANDS, dtype=np.int64),
                     np.zeros(len(RATE_EDGES) + 1), np.zeros(len(RATE_EDGES) + 1, dtype=np.int64), 0.0)

    def feed(self, t_last: float, residual: np.ndarray, drive: np.ndarray, tracking: np.ndarray) -> None:
        """The ticks since the last call, in order: residual (NaN where not judged), the drive it
        answers, the tracking error; `t_last` the loop time of the last of them."""
        residual = np.asarray(residual, dtype=float)
        if residual.size == 0:
            return
        block = self._block(residual, np.asarray(drive, dtype=float), np.asarray(tracking, dtype=float))
        self.last_t = float(t_last)
        if block.n == 0:
            return
        self.blocks.append(block)
        self._add(block, 1)
        while len(self.blocks) > 1 and self.total.n - self.blocks[0].n >= self.window_n:
            self._add(self.blocks.popleft(), -1)
        if self.total.n >= self.window_n:
            self._judge(self.last_t)

    def _block(self, r: np.ndarray, u: np.ndarray, e: np.ndarray) -> Block:
        ok = np.isfinite(r)
        sq = np.where(ok, r, 0.0) ** 2
        joined = np.concatenate([self.tail_residual, r])
        d2 = joined[2:] - 2.0 * joined[1:-1] + joined[:-2]          # NaN wherever a judged run is broken
        d2 = d2[np.isfinite(d2)]
        du = np.abs(np.diff(np.concatenate([[self.tail_drive], u]))) / self.period_s
        rated = ok & np.isfinite(du)
        self.tail_residual = joined[-2:].copy()
        self.tail_drive = float(u[-1])
        position = np.where(np.isfinite(u), u - self.lo, 0.0) * (DRIVE_BANDS / self.span)
        bands = np.clip(position.astype(int), 0, DRIVE_BANDS - 1)
        rates = np.searchsorted(self.rate_edges, np.where(rated, du, 0.0), side="right")
        nb, nr = DRIVE_BANDS, len(RATE_EDGES) + 1
        return Block(int(ok.sum()), float(sq.sum()), float(d2 @ d2), int(d2.size),
                     np.bincount(bands[ok], sq[ok], nb), np.bincount(bands[ok], minlength=nb),
                     np.bincount(rates[rated], sq[rated], nr), np.bincount(rates[rated], minlength=nr),
                     float(np.where(ok, e, 0.0) @ np.where(ok, e, 0.0)))

    def _add(self, b: Block, sign: int) -> None:
        tot = self.total
        tot.n += sign * b.n
        tot.sq += sign * b.sq
        tot.d2_sq += sign * b.d2_sq
        tot.d2_n += sign * b.d2_n
        tot.band_sq += sign * b.band_sq
        tot.band_n += sign * b.band_n
        tot.rate_sq += sign * b.rate_sq
        tot.rate_n += sign * b.rate_n
        tot.tracking_sq += sign * b.tracking_sq

    @property
    def noise_sq(self) -> float:
        return self.total.d2_sq / (6.0 * self.total.d2_n) if self.total.d2_n else 0.0

    def _judge(self, t: float) -> None:
        ms = max(self.total.sq, 0.0) / self.total.n
        if self.ref_sq != self.ref_sq:           # no identification error on file: this window is the reference
            self.ref_sq = ms
        expected = self.ref_sq + self.noise_sq
        self.ratio = math.sqrt(ms / expected) if expected > 0.0 else math.inf
        if self.state == DRIFTING:
            if self.ratio < CLEAR_RATIO:
                self.state, self.since_t = OK, t
        elif self.ratio > DRIFT_RATIO:
            self.from_start = self.state == UNKNOWN
            self.state, self.since_t = DRIFTING, t
        elif self.state == UNKNOWN:
            self.state, self.since_t = OK, t

    # ---- reporting -------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """The state, the ratio and its parts, since when, and where the residual sits."""
        tot = self.total
        n = tot.n
        return {
            "state": self.state,
            "since_s": _finite(self.since_t),
            "from_start": self.from_start and self.state == DRIFTING,
            "t_s": _finite(self.last_t),
            "ratio": _finite(self.ratio),
            "residual_rms_um": math.sqrt(max(tot.sq, 0.0) / n) if n else None,
            "identification_rms_um": _finite(math.sqrt(self.ref_sq)) if self.ref_sq == self.ref_sq else None,
            "noise_floor_um": math.sqrt(self.noise_sq) if tot.d2_n else None,
            "reference": self.reference_words,
            "thresholds": {"drifting_above": DRIFT_RATIO, "ok_below": CLEAR_RATIO},
            "window": {"ticks": n, "of": self.window_n, "seconds": n * self.period_s,
                       "window_s": self.window_n * self.period_s},
            "tracking_rms_um": math.sqrt(max(tot.tracking_sq, 0.0) / n) if n else None,
            "where": self.where() if n else None,
        }

    def where(self) -> dict[str, Any]:
        """The drive band and the drive-rate band with the largest residual RMS in the window."""
        width = self.span / DRIVE_BANDS
        bands = [(self.lo + k * width, self.lo + (k + 1) * width) for k in range(DRIVE_BANDS)]
        edges = [0.0, *self.rate_edges.tolist(), math.inf]
        rates = [(edges[k], edges[k + 1]) for k in range(len(edges) - 1)]
        tot = self.total
        return {"drive": _largest(bands, tot.band_sq, tot.band_n),
                "drive_rate_per_s": _largest(rates, tot.rate_sq, tot.rate_n)}


def _largest(ranges: list[tuple[float, float]], sq: np.ndarray, n: np.ndarray) -> dict[str, Any] | None:
    total = int(n.sum())
    rows = [(math.sqrt(max(s, 0.0) / c), r, int(c)) for s, c, r in zip(sq.tolist(), n.tolist(), ranges)
            if c > 0 and c >= MIN_BAND_SHARE * total]
    if not rows:
        return None
    rms, (lo, hi), count = max(rows)
    return {"range": [_finite(lo), _finite(hi)], "rms_um": rms, "share": count / total}


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None
