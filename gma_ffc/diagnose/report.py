"""Show the diagnosis: diagnosis.json, report.html (plots first, numbers behind), extended_model.yaml.

Everything is rendered in memory first, then written with `atomic_write_all`: every file as a
temporary, renamed only once all are written, so a failure while plotting or writing (a full disk)
leaves the folder's earlier set as it was, never half-written nor a mix of two runs.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..atomic import atomic_write_all
from ..errors import FaultError
from .data import unscored_spans
from .results import Diagnosis, rms_summary, written_summary

MODEL_FILE = "extended_model.yaml"


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig: Any) -> str:
    plt = _plt()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _thin(n: int, target: int = 6000) -> slice:
    return slice(None, None, max(1, n // target))


def _drive_label(d: Any) -> str:
    return "drive voltage (V)" if d.extra.get("drive_symbol") == "V" else "drive current (A)"


def _unchanged(dg: Diagnosis) -> bool:
    """Nothing was accepted: the extended model predicts what the base model does. Drawn as two
    lines, the base would hide under the extended one while the legend still names both."""
    return all(yb.shape == yf.shape and np.allclose(yb, yf, rtol=0.0, atol=1e-9)
               for yb, yf in zip(dg.base_predictions, dg.final_predictions))


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(np.square(a)))) if a.size else float("nan")


def _legend_outside(ax: Any) -> None:
    """Legends beside the panel, never on the data."""
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, frameon=False)


def _time_axis(ax: Any) -> None:
    """The x-axis in seconds, its ticks the times themselves: a short window late in a long run
    read '0.040 ... +1.5e2' (matplotlib's offset), which a reader takes for 0.04 s."""
    ax.set_xlabel("time (s)")
    ax.ticklabel_format(axis="x", useOffset=False)


def plot_residuals(dg: Diagnosis, render: Any = None) -> Any:
    plt = _plt()
    n = len(dg.data)
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.5 * n + 0.4), squeeze=False, constrained_layout=True)
    same = _unchanged(dg)
    for ax, d, loc, yb, yn, yf in zip(axes[:, 0], dg.data, dg.located, dg.base_predictions,
                                     dg.null_predictions, dg.final_predictions):
        sl = _thin(d.t.size)
        if not same:
            ax.plot(d.t[sl], (d.y - yb)[sl], lw=0.6, color="0.6", label="base model")
        ax.plot(d.t[sl], (d.y - yn)[sl], lw=0.7, color="tab:orange", label="recalibrated")
        ax.plot(d.t[sl], (d.y - yf)[sl], lw=0.7, color="tab:blue",
                label="base model (= extended: nothing accepted)" if same else "extended")
        ax.axvspan(*loc.window_s, color="tab:red", alpha=0.12, label="largest residual")
        for i, (a, b) in enumerate(unscored_spans(d)):
            ax.axvspan(a, b, color="0.85", alpha=0.6, label="not scored (initial state)" if i == 0 else None)
        for i, jump in enumerate(d.jumps.found):
            ax.axvline(jump.t_s, color="tab:purple", ls="--", lw=0.9,
                       label="sensor's zero steps (allowed for in every fit)" if i == 0 else None)
        _scale_to_scored(ax, d, ([] if same else [d.y - yb]) + [d.y - yn, d.y - yf])
        ax.set_title(d.name, fontsize=9)
        ax.set_ylabel("residual (um)")
        _time_axis(ax)
        _legend_outside(ax)
    return (render or _png)(fig)      # render=lambda fig: fig hands tests the figure


def _scale_to_scored(ax: Any, d: Any, residuals: list[np.ndarray]) -> None:
    """The y-axis over the scored samples: an unscored start (the state settling, greyed) can swing
    tens of times wider and flattened the residual the diagnosis judged (-35 um against 1 um on a
    measured piezo). The grey span says what is cut there."""
    keep = np.asarray(d.mask, dtype=bool)
    if not keep.any() or keep.all():
        return
    values = np.concatenate([r[keep] for r in residuals])
    values = values[np.isfinite(values)]
    if values.size:
        lo, hi = float(values.min()), float(values.max())
        pad = 0.08 * max(hi - lo, 1e-9)
        ax.set_ylim(lo - pad, hi + pad)


# a crossing counts once the drive has gone this share of the recording's drive range past the
# middle of its swing: a drive held at rest, its measured noise crossing its own middle, is no cycle
CROSSING_BAND_SHARE = 0.05


def _crossings(u: np.ndarray, band: float = 0.0) -> int:
    """How often the drive crosses the middle of its swing (two per cycle), from below `mid - band`
    to above `mid + band` or back (the noise of a drive at rest within the band counts nothing)."""
    seg = u - 0.5 * (float(np.min(u)) + float(np.max(u)))
    side = np.sign(seg) * (np.abs(seg) > band)
    side = side[side != 0]
    return int(np.sum(side[1:] != side[:-1]))


def _window(d: Any, span_s: tuple[float, float], whole_cycle: bool = False) -> slice:
    """About five drive cycles at the start of the time span (at most 4000 samples). With
    `whole_cycle`, a span holding less than one cycle is lengthened (up to four times, and up to
    20000 samples) until the drive has gone out and back: a loop panel drawn from part of a slow
    sine shows half a loop."""
    a = int(np.searchsorted(d.t, span_s[0]))
    b = max(int(np.searchsorted(d.t, span_s[1])), a + 2)
    n = d.t.size
    lo, hi = np.percentile(d.u, [1.0, 99.0])
    band = CROSSING_BAND_SHARE * float(hi - lo)
    limit = min(a + 4 * (b - a), n)
    while whole_cycle and b < limit and _crossings(d.u[a:b], band) < 3:
        b = min(b + max((b - a) // 2, 1), limit)
    c = _crossings(d.u[a:b], band)
    if c >= 10:
        b = a + max(int(10 * (b - a) / c), 20)
    return slice(a, min(b, a + (20000 if whole_cycle else 4000), n))


# a loop is only drawn where the drive sweeps at least this share of its range in the recording,
# continuously (no jump over a quarter of its swing) and through the middle of its swing (a sine
# spends 1/3 of its time in the middle half): a pause, a step or a staircase plots as a blob or a
# line, whatever its residual
LOOP_SWEEP_SHARE = 0.5
LOOP_MIDDLE_SHARE = 0.2
LOOP_MAX_JUMP = 0.25


def _sweeps(u: np.ndarray, need: float) -> bool:
    lo, hi = float(np.min(u)), float(np.max(u))
    if hi - lo < need or float(np.max(np.abs(np.diff(u)))) > LOOP_MAX_JUMP * (hi - lo):
        return False
    mid = np.abs(u - 0.5 * (lo + hi)) < 0.25 * (hi - lo)
    return float(np.mean(mid)) >= LOOP_MIDDLE_SHARE


def _shown(d: Any, loc: Any, score: np.ndarray, sweep: bool) -> tuple[slice, bool]:
    """The samples a panel shows: of the windows `_window` cuts (starts a quarter of the located
    window's length apart, at most about 400 of them, after the unscored start), the one where the
    per-sample `score` (a squared residual, or its fall) is highest on average; with `sweep`, only
    among windows where the drive sweeps a loop. Also says whether that window sweeps (False: none
    does, and the located window is shown)."""
    t, n = d.t, d.t.size
    lo, hi = np.percentile(d.u, [1.0, 99.0])
    need = LOOP_SWEEP_SHARE * float(hi - lo)
    first = min(d.settled, n - 1)
    length = loc.window_s[1] - loc.window_s[0]
    width = max(int(np.searchsorted(t, t[first] + length)) - first if length > 0 else (n - first) // 16, 20)
    csum = np.concatenate(([0.0], np.cumsum(np.nan_to_num(score))))
    best, best_val = None, -np.inf
    for a in range(first, max(n - width, first) + 1, max(width // 4, (n - first) // 400, 1)):
        w = _window(d, (float(t[a]), float(t[min(a + width, n) - 1])), whole_cycle=sweep)
        if w.stop - w.start < 2 or (sweep and not _sweeps(d.u[w], need)):
            continue
        val = (csum[w.stop] - csum[w.start]) / (w.stop - w.start)
        if val > best_val:
            best, best_val = w, val
    return (_window(d, loc.window_s, whole_cycle=sweep), False) if best is None else (best, True)


def _located_loops(d: Any, loc: Any, yf: np.ndarray) -> tuple[slice, bool]:
    """With nothing named: the located window itself where the drive sweeps a loop there, so the
    panel titled "where the residual is largest" shows the window the text names (they differed:
    t = 5.6-7.1 s drawn, t = 1.5-3.0 s located); else the window of the largest residual that does."""
    w = _window(d, loc.window_s, whole_cycle=True)
    lo, hi = np.percentile(d.u, [1.0, 99.0])
    if w.stop - w.start >= 2 and _sweeps(d.u[w], LOOP_SWEEP_SHARE * float(hi - lo)):
        return w, True
    return _shown(d, loc, np.square(d.y - yf), sweep=True)


def _fall(d: Any, yb: np.ndarray, yf: np.ndarray) -> np.ndarray:
    """Per sample, how much the squared residual falls from the base model to the extended one."""
    return np.square(d.y - yb) - np.square(d.y - yf)


def _overlay_title(name: str, named: bool, helps: bool) -> str:
    """The before-and-after panel's title. With effects named the panel shows where they help most
    (`_shown`); where even there the extended model misses by more than the base, they help nowhere
    on this recording, and the title says so (its legend's two RMS figures said it against the title)."""
    if not named:
        return f"{name}: where the residual is largest"
    if helps:
        return f"{name}: where the named effects help most"
    return f"{name}: the named effects do not help on it (least harm shown)"


def plot_overlays(dg: Diagnosis, render: Any = None) -> Any:
    """Measured against base and extended where the residual is largest, and beside it the two
    residuals on their own scale (on the displacement scale a 0.3 um improvement is invisible)."""
    plt = _plt()
    n = len(dg.data)
    fig, axes = plt.subplots(n, 2, figsize=(12, 2.7 * n + 0.4), squeeze=False, constrained_layout=True,
                             gridspec_kw={"width_ratios": [1.2, 1.0]})
    same = _unchanged(dg)
    named = bool(dg.verdict)
    for (ax, axr), d, loc, yb, yf in zip(axes, dg.data, dg.located, dg.base_predictions, dg.final_predictions):
        # with effects named, where they change the fit most (where the residual is largest can be where
        # the base was already right, e.g. a cold start before the heating); else the residual's place
        w = _window(d, loc.window_s) if not named else _shown(d, loc, _fall(d, yb, yf), sweep=False)[0]
        a, b = w.start, w.stop
        ax.plot(d.t[a:b], d.y[a:b], lw=1.2, color="k", label="measured")
        if not same:
            ax.plot(d.t[a:b], yb[a:b], lw=0.9, color="0.55", ls="--", label="base model")
        ax.plot(d.t[a:b], yf[a:b], lw=0.9, color="tab:blue",
                label="base model (= extended)" if same else "extended model")
        ax.set_title(_overlay_title(d.name, named, _rms((d.y - yf)[a:b]) < _rms((d.y - yb)[a:b])), fontsize=9)
        ax.set_ylabel("displacement (um)")
        _time_axis(ax)
        _legend_outside(ax)
        axr.axhline(0.0, color="0.8", lw=0.8)
        # the RMS in the legend: beside a residual ten times larger, the smaller one reads as a flat line
        if not same:
            axr.plot(d.t[a:b], (d.y - yb)[a:b], lw=0.9, color="0.55",
                     label=f"measured - base (RMS {_rms((d.y - yb)[a:b]):.3g} um)")
        axr.plot(d.t[a:b], (d.y - yf)[a:b], lw=0.9, color="tab:blue",
                 label=f"measured - {'model' if same else 'extended'} (RMS {_rms((d.y - yf)[a:b]):.3g} um)")
        axr.set_title("residual, own scale" if same else "residuals, own scale", fontsize=9)
        axr.set_ylabel("residual (um)")
        _time_axis(axr)
        _legend_outside(axr)
    return (render or _png)(fig)      # render=lambda fig: fig hands tests the figure


def plot_loops(dg: Diagnosis, render: Any = None) -> Any:
    """Displacement against drive where the residual (or its fall) is largest; None when the drive
    sweeps no loop anywhere (a step test), where such a chart would show a scribble."""
    named = bool(dg.verdict)
    shown = [_shown(d, loc, _fall(d, yb, yf), sweep=True) if named else _located_loops(d, loc, yf)
             for d, loc, yb, yf in zip(dg.data, dg.located, dg.base_predictions, dg.final_predictions)]
    if not any(sweeps for _, sweeps in shown):
        return None
    plt = _plt()
    n = len(dg.data)
    cols = min(n, 2)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 3.4 * rows + 0.4), squeeze=False,
                             constrained_layout=True)
    same = _unchanged(dg)
    for ax, d, yb, yf, (w, sweeps) in zip(axes.flat, dg.data, dg.base_predictions, dg.final_predictions, shown):
        ax.plot(d.u[w], d.y[w], lw=1.2, color="k", label="measured")
        if not same:
            ax.plot(d.u[w], yb[w], lw=0.9, ls="--", color="0.55", label="base")
        ax.plot(d.u[w], yf[w], lw=0.9, color="tab:blue", label="base (= extended)" if same else "extended")
        ax.set_title(f"{d.name}, t = {d.t[w.start]:.4g}-{d.t[w.stop - 1]:.4g} s"
                     + ("" if sweeps else " (the drive sweeps no loop here)"), fontsize=9)
        ax.set_xlabel(_drive_label(d))
        ax.set_ylabel("displacement (um)")
        _legend_outside(ax)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    return (render or _png)(fig)      # render=lambda fig: fig hands tests the figure


def plot_candidates(dg: Diagnosis, render: Any = None) -> Any:
    plt = _plt()
    cands = [c for c in dg.candidates if math.isfinite(c.cv_mse)]
    fig, ax = plt.subplots(figsize=(9, 0.45 * max(len(cands), 1) + 1.4), constrained_layout=True)
    names = [c.effect for c in cands]
    vals = [math.sqrt(c.cv_mse) for c in cands]
    colors = ["tab:blue" if c.accepted else "0.6" for c in cands]
    ax.barh(names, vals, color=colors)
    ax.axvline(dg.rms_recalibrated_um, color="tab:orange", ls="--", label="recalibrated base (null)")
    ax.axvline(dg.noise_um, color="tab:green", ls=":", label="noise floor")
    if dg.verdict:
        # each bar is from the round the effect was last tried in, with the effects accepted before it
        # in place: an accepted one's bar is its own round's, and the model with all of them ends here
        ax.axvline(dg.rms_after_um, color="tab:blue", ls="-.", label="extended model (final)")
    ax.set_xlabel("held-out RMS (um) in the round each effect was last tried (with the effects accepted before it)")
    ax.set_ylabel("candidate effect (blue: accepted)")
    ax.invert_yaxis()
    _legend_outside(ax)
    return (render or _png)(fig)      # render=lambda fig: fig hands tests the figure


HEADLINES = {   # outcome -> (headline, colour, one sentence a reader takes away)
    "within_noise": ("Within noise", "#2e7d32", "The model explains the recordings within their noise: no missing "
                                                 "physics is needed."),
    "effects_named": ("Missing physics found", "#1565c0", "Effects the model leaves out were found, modelled and shown "
                                                          "to help on data the fit did not see."),
    "unexplained": ("Unexplained residual", "#c62828", "The residual is well above the noise and nothing in the "
                                                       "vocabulary explains it: the core's error on a drive unlike "
                                                       "its identification data, the limit of its class, or physics "
                                                       "not in the vocabulary (the explanation says what would narrow "
                                                       "it down)."),
    "inconclusive": ("Inconclusive", "#ef6c00", "The data cannot decide: see 'What cannot be concluded' for the "
                                                "recording that would."),
}


def headline(dg: Diagnosis, recalibrated: bool) -> tuple[str, str, str]:
    """The report's headline, its colour and the sentence under it. With nothing named but the
    model `recalibrated` (`recalibration_words` found a change), the outcome's words alone would read
    as if the model given were the one that fits: the headline says nothing was found missing and
    that the model was recalibrated."""
    title, colour, sentence = HEADLINES[dg.outcome]
    if dg.verdict:
        title += ": " + ", ".join(name + (" (tentative)" if name in dg.tentative else "") for name in dg.verdict)
        return title, colour, sentence
    if not recalibrated:
        return title, colour, sentence
    if dg.outcome == "within_noise":
        return ("Nothing missing: the model was recalibrated", colour,
                "No physics is missing from the model. Recalibrated (below), it explains the recordings "
                "within their noise; nothing was added to it.")
    return f"{title}: nothing named, the model was recalibrated", colour, sentence


def recalibration_words(dg: Diagnosis) -> str:
    """What the extended model's static recalibration changes, in words; '' when it changes nothing
    (the model given is written as it was)."""
    st = dg.extended.static
    s = st.static
    parts = []
    if s["gain"] != 1.0:
        parts.append(f"gain x{s['gain']:.4g} ({100 * (s['gain'] - 1):+.3g} %)")
    if s["offset_um"] != 0.0:
        parts.append(f"offset {s['offset_um']:+.3g} um")
    if s["quadratic_per_um"] != 0.0:
        parts.append(f"curvature {s['quadratic_per_um']:+.3g} per um about {s['center_um']:.4g} um")
    if s["stress_gain_per_MPa"] != 0.0:
        parts.append(f"gain {s['stress_gain_per_MPa']:+.3g} per MPa away from {s['stress_ref_MPa']:.3g} MPa")
    if np.any(st.coefficients != 0.0):
        # each play's output minus its input swings over +-threshold: rising and falling branches
        # move apart (or together) by twice the threshold times the play's weight
        width = float(np.sum(2.0 * np.abs(st.coefficients) * st.thresholds))
        parts.append(f"loop width changed by up to {width:.3g} um")
    if not parts:
        return ""
    moved = max((float(np.max(np.abs(yf - yb))) for yb, yf in zip(dg.base_predictions, dg.final_predictions)
                 if yb.shape == yf.shape and yb.size), default=0.0)
    return (f"What the recalibration changed: {', '.join(parts)}. It moves the prediction by up to {moved:.3g} um; "
            f"the change in held-out RMS above is its alone. {MODEL_FILE} is the model given with this "
            "recalibration, and no physics added.")


def candidates_table(doc: dict) -> str:
    """The report's table of every candidate effect: accepted or not, its figures and why."""
    e = html.escape
    rows = ["<h2>Candidates</h2><table><tr><th>effect</th><th>accepted</th><th>held-out RMS (um)</th>"
            "<th>held-out log-lik gain</th><th>evidence</th><th>parameters</th><th>note</th></tr>"]
    for c in doc["candidates"]:
        params = ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}" for k, v in c["params"].items())
        rms = "" if c["validation_rms_um"] is None else f"{c['validation_rms_um']:.4g}"
        ll = "" if c["heldout_loglik_gain"] is None else f"{c['heldout_loglik_gain']:.1f}"
        rows.append(f"<tr><td>{e(c['effect'])}</td><td>{'yes' if c['accepted'] else ''}</td><td>{rms}</td>"
                    f"<td>{ll}</td><td>{c['evidence']:.3f}</td><td>{e(params)}</td><td>{e(c.get('note', ''))}</td></tr>")
    return "".join(rows) + "</table>"


def rounds_table(doc: dict) -> str:
    """The report's table of the selection rounds: every candidate each round scored, best first,
    with its figures and its decision (accepted, or why it was set aside); '' with no round."""
    if not doc["rounds"]:
        return ""
    e = html.escape
    rows = ["<h2>Selection rounds</h2><table><tr><th>round</th><th>RMS at start (um)</th><th>n_eff</th>"
            "<th>candidate</th><th>held-out RMS (um)</th><th>gain (nats)</th><th>decision</th></tr>"]
    for r in doc["rounds"]:          # the round's figures once, beside its first candidate
        span = f"<td rowspan='{len(r['scored'])}'>"
        head = (f"{span}{r['round']}</td>{span}{_figure(r['rms_at_start_um'], '.4g')}</td>"
                f"{span}{_figure(r['n_eff'], '.0f')}</td>")
        for c in r["scored"]:
            name = e(c["effect"])
            rows.append(f"<tr>{head}<td>{f'<b>{name}</b>' if c['effect'] == r['accepted'] else name}</td>"
                        f"<td>{_figure(c['validation_rms_um'], '.4g')}</td>"
                        f"<td>{_figure(c['heldout_loglik_gain'], '.1f')}</td><td>{e(c['decision'])}</td></tr>")
            head = ""
    return "".join(rows) + "</table>"


def _figure(v: float | None, spec: str) -> str:
    """A figure of a table, or '-' where none was measured (null in diagnosis.json)."""
    return "-" if v is None else format(v, spec)


def render_html(dg: Diagnosis, doc: dict) -> str:
    overlay = ("Where the residual is largest: measured and model (nothing was accepted, so there is no "
               "'after'), and the residual" if _unchanged(dg) else
               "Before and after: measured, base and extended model, and their residuals")
    imgs = [("Residual over time, where it was found", plot_residuals(dg)),
            (overlay, plot_overlays(dg)),
            ("Loops where the named effects help most: displacement against drive" if dg.verdict else
             "Loops where the residual is largest: displacement against drive", plot_loops(dg))]
    imgs = [(title, img) for title, img in imgs if img is not None]      # no loop chart without a loop
    if any(math.isfinite(c.cv_mse) for c in dg.candidates):      # no empty chart when nothing was tried
        imgs.append(("Candidates: held-out RMS", plot_candidates(dg)))
    e = html.escape
    summary = rms_summary(doc)
    recalibrated = "" if dg.verdict else recalibration_words(dg)
    title, colour, sentence = headline(dg, bool(recalibrated))
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'><title>gma-ffc diagnosis</title>",
             "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}"
             "table{border-collapse:collapse}td,th{border:1px solid #bbb;padding:3px 6px;font-size:13px}"
             "img{max-width:100%}.headline{padding:10px 14px;border-radius:6px;color:#fff}"
             "pre{white-space:pre-wrap;word-break:break-word}</style></head><body>",
             f"<h1 class='headline' style='background:{colour}'>{e(title)}</h1>",
             f"<p><b>{e(sentence)}</b></p>",
             f"<p><b>{e(summary[:1].upper() + summary[1:])}</b></p>"]
    if recalibrated:
        parts.append(f"<p><b>{e(recalibrated)}</b></p>")
    written = written_summary(doc)
    if written:
        parts.append(f"<p>{e(written[:1].upper() + written[1:])}.</p>")
    # which recordings the base was identified on, and whether they were given: the command prints it
    # beside the outcome; a reader of the report alone would not know the data were the model's own
    parts.append(f"<p>Identification recordings: {e(doc['identification']['note'])}</p>")
    for title, data in imgs:
        parts.append(f"<h2>{e(title)}</h2><img alt='{e(title)}' src='data:image/png;base64,{data}'>")
    parts.append(f"<h2>Explanation</h2><p>{e(dg.explanation)}</p>")
    if dg.cannot_conclude:
        parts.append("<h2>What cannot be concluded</h2><ul>" +
                     "".join(f"<li>{e(x)}</li>" for x in dg.cannot_conclude) + "</ul>")
    parts.append(candidates_table(doc))
    parts.append("<h2>Where the residual is</h2><table><tr><th>recording</th><th>where</th>"
                 "<th>RMS base (um)</th><th>RMS recalibrated (um)</th></tr>")
    for loc in doc["located"]:
        parts.append(f"<tr><td>{e(loc['recording'])}</td><td>{e(loc['where'])}</td>"
                     f"<td>{loc['residual_rms_um']:.4g}</td><td>{loc['residual_rms_recalibrated_um']:.4g}</td></tr>")
    parts.append("</table>")
    parts.append(rounds_table(doc))
    parts.append(f"<h2>Validation</h2><p>{e(dg.validation)}</p>")
    parts.append(f"<h2>Extended model</h2><p><a href='{MODEL_FILE}'>{MODEL_FILE}</a>: blocks "
                 f"{e(', '.join(k for k, v in dg.extended.blocks().items() if v))}; "
                 f"invert and the controller compensate them as listed under 'inverted' in the file.</p>")
    parts.append("<details><summary>diagnosis.json (as written beside this report)</summary><pre>"
                 + e(json.dumps(doc, indent=1)) + "</pre></details></body></html>")
    return "".join(parts)


def model_yaml(dg: Diagnosis) -> str:
    d = dg.extended.to_dict()
    header = ("# gma-ffc model (extended), written by gma-ffc diagnose. Units: drive in A (or V), displacement\n"
              "# in um, stress in MPa (compression negative), time in s. Validated on load.\n")
    return header + yaml.safe_dump(d, sort_keys=False, default_flow_style=None, width=100)


def finite_document(v: Any, where: str = "diagnosis.json") -> Any:
    """The document in plain JSON types (numpy scalars as numbers), refusing any NaN or infinite
    number: what a field cannot say is null by design (an effect never tried has no held-out RMS),
    so a non-finite number is a defect, and nothing is written rather than a number that is none."""
    if isinstance(v, dict):
        return {k: finite_document(x, f"{where}.{k}") for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [finite_document(x, f"{where}[{i}]") for i, x in enumerate(v)]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        if not math.isfinite(v):
            raise FaultError(f"{where} would be {float(v)} (a defect in gma-ffc diagnose; nothing was written: "
                             "please report it with the recordings)")
        return float(v)
    return v


def write_outputs(dg: Diagnosis, out_dir: str | Path) -> dict:
    """Render everything, then write the three files atomically, all or none; returns the JSON document."""
    out = Path(out_dir)
    doc = finite_document(dg.to_json(MODEL_FILE))
    js = json.dumps(doc, indent=2, allow_nan=False)
    page = render_html(dg, doc)
    ym = model_yaml(dg)
    atomic_write_all(out, {MODEL_FILE: ym.encode("utf-8"), "report.html": page.encode("utf-8"),
                           "diagnosis.json": js.encode("utf-8")})
    return doc
