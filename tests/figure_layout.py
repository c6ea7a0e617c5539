"""Check a matplotlib figure the way a reader looks at it: no text on top of other text (titles,
axis labels, tick labels, legends of different axes), no legend on top of the data of any panel
(lines between their points, bars, shaded spans, markers), and a label with a unit on both axes of
every panel that shows data (a category axis, such as a bar chart's names, needs a label only)."""

from __future__ import annotations

import re
from typing import Any

import numpy as np

# "displacement (um)", "time [s]", "rate (um/s)", "heat (A^2 s)": what is in the brackets must be
# made of units, so "residual (fitted)" or "effect (blue: accepted)" is no unit
UNIT = re.compile(r"[\[(]([^\])]+)[\])]")
UNITS = {"um", "µm", "nm", "mm", "m", "s", "ms", "us", "min", "h", "A", "mA", "V", "mV", "MPa", "Pa", "kPa",
         "N", "Hz", "kHz", "C", "K", "W", "J", "%", "dB", "rad", "deg", "nats", "1"}


def _has_unit(text: str) -> bool:
    for inside in UNIT.findall(text):
        tokens = [t for t in re.split(r"[\s/*·^()-]+|\d+", inside) if t]
        if tokens and all(t in UNITS for t in tokens):
            return True
    return False


def _is_category(axis: Any) -> bool:
    """Names on the axis (a bar chart's categories), not numbers: no unit to give."""
    from matplotlib.category import UnitData

    return isinstance(axis.get_units(), UnitData)


def _texts(ax: Any, renderer: Any) -> list[tuple[str, Any]]:
    out = []
    for label, artist in (("title", ax.title), ("xlabel", ax.xaxis.label), ("ylabel", ax.yaxis.label)):
        if artist.get_text() and artist.get_visible():
            out.append((label, artist.get_window_extent(renderer)))
    (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
    for axis, lo, hi in ((ax.xaxis, x0, x1), (ax.yaxis, y0, y1)):
        for tick in axis.get_major_ticks():
            label = tick.label1
            if label.get_text() and label.get_visible() and lo <= tick.get_loc() <= hi:   # drawn ticks only
                out.append(("tick", label.get_window_extent(renderer)))
    leg = ax.get_legend()
    if leg is not None and leg.get_visible():
        out.append(("legend", leg.get_window_extent(renderer)))
    for text in ax.texts:
        if text.get_text() and text.get_visible():
            out.append(("text", text.get_window_extent(renderer)))
    return out


def _segments_hit(pts: np.ndarray, box: Any) -> bool:
    """Does the polyline through `pts` (display coordinates) cross the box, between its points too?"""
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        return False
    if len(pts) == 1:
        pts = np.vstack([pts, pts])
    p0, d = pts[:-1], np.diff(pts, axis=0)
    t0, t1 = np.zeros(len(d)), np.ones(len(d))
    ok = np.ones(len(d), bool)
    for k, (lo, hi) in enumerate(((box.x0, box.x1), (box.y0, box.y1))):     # Liang-Barsky clipping
        for q, dd in ((p0[:, k] - lo, -d[:, k]), (hi - p0[:, k], d[:, k])):
            para = dd == 0
            ok &= ~(para & (q < 0))
            with np.errstate(divide="ignore", invalid="ignore"):
                r = np.where(para, 0.0, q / np.where(para, 1.0, dd))
            t0 = np.where(~para & (dd < 0), np.maximum(t0, r), t0)
            t1 = np.where(~para & (dd > 0), np.minimum(t1, r), t1)
    return bool(np.any(ok & (t0 <= t1)))


def _name(artist: Any, kind: str) -> str:
    label = str(artist.get_label())
    return f"an unlabelled {kind}" if label.startswith("_") else repr(label)


def _covered(ax: Any, box: Any, renderer: Any) -> str | None:
    """What the first piece of data of `ax` under `box` (inside the panel) is, else None."""
    inside = ax.get_window_extent(renderer)
    x0, x1 = max(box.x0, inside.x0), min(box.x1, inside.x1)
    y0, y1 = max(box.y0, inside.y0), min(box.y1, inside.y1)
    if x1 - x0 <= 1.0 or y1 - y0 <= 1.0:
        return None                                   # the box is beside the panel, not on it
    from matplotlib.transforms import Bbox

    clip = Bbox.from_extents(x0, y0, x1, y1)
    for line in ax.get_lines():
        if line.get_visible() and len(line.get_xydata()):
            if _segments_hit(line.get_transform().transform(line.get_xydata()), clip):
                return _name(line, "line")
    for patch in ax.patches:                          # bars, shaded spans
        if patch.get_visible():
            e = patch.get_window_extent(renderer)
            if min(e.x1, clip.x1) - max(e.x0, clip.x0) > 1.0 and min(e.y1, clip.y1) - max(e.y0, clip.y0) > 1.0:
                return _name(patch, "bar or span")
    for coll in ax.collections:                       # markers
        offsets = coll.get_offsets()
        if coll.get_visible() and len(offsets):
            pts = coll.get_offset_transform().transform(offsets)
            if np.any((pts[:, 0] > clip.x0) & (pts[:, 0] < clip.x1) & (pts[:, 1] > clip.y0) & (pts[:, 1] < clip.y1)):
                return _name(coll, "marker")
    return None


def layout_problems(fig: Any) -> list[str]:
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    axes = [ax for ax in fig.axes if ax.get_visible() and ax.has_data()]
    problems = []
    for i, ax in enumerate(axes):
        for which, axis in (("x", ax.xaxis), ("y", ax.yaxis)):
            text = axis.label.get_text().strip()
            if not text:
                problems.append(f"panel {i} ({ax.get_title()!r}): no {which} axis label")
            elif not _has_unit(text) and "period" not in text and not _is_category(axis):
                problems.append(f"panel {i}: {which} label {text!r} has no unit")
        leg = ax.get_legend()
        if leg is not None and leg.get_visible():
            box = leg.get_window_extent(renderer)
            for j, other in enumerate(axes):          # its own panel's data, or a neighbour's
                what = _covered(other, box, renderer)
                if what is not None:
                    where = "" if j == i else f" of panel {j}"
                    problems.append(f"panel {i}: the legend covers data{where} of {what}")
                    break
    boxes = [(i, kind, bb) for i, ax in enumerate(axes) for kind, bb in _texts(ax, renderer)]
    for suptitle in [t for t in fig.texts if t.get_text()] + ([fig._suptitle] if getattr(fig, "_suptitle", None) else []):
        boxes.append((-1, "suptitle", suptitle.get_window_extent(renderer)))
    for a in range(len(boxes)):
        for b in range(a + 1, len(boxes)):
            (i, ka, ba), (j, kb, bb) = boxes[a], boxes[b]
            if i == j and not ({ka, kb} & {"legend", "title"}):
                continue          # an axes' own ticks and labels are placed by matplotlib
            if i == j and ka == kb == "tick":
                continue
            w = min(ba.x1, bb.x1) - max(ba.x0, bb.x0)
            h = min(ba.y1, bb.y1) - max(ba.y0, bb.y0)
            if w > 1.0 and h > 1.0:                      # more than touching: ink on ink
                problems.append(f"{ka} of panel {i} overlaps {kb} of panel {j}")
    return sorted(set(problems))
