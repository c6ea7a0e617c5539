"""Check a matplotlib figure the way a reader looks at it: no text on top of other text (titles,
axis labels, tick labels, legends of different axes), no legend on top of the data, and a label
with a unit on both axes of every panel that shows data."""

from __future__ import annotations

import re
from typing import Any

UNIT = re.compile(r"[\[(][^\])]+[\])]")     # "displacement (um)", "time [s]"


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
    return out


def layout_problems(fig: Any) -> list[str]:
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    axes = [ax for ax in fig.axes if ax.get_visible() and ax.has_data()]
    problems = []
    for i, ax in enumerate(axes):
        for which in ("x", "y"):
            text = (ax.get_xlabel() if which == "x" else ax.get_ylabel()).strip()
            if not text:
                problems.append(f"panel {i} ({ax.get_title()!r}): no {which} axis label")
            elif not UNIT.search(text) and "period" not in text:
                problems.append(f"panel {i}: {which} label {text!r} has no unit")
        leg = ax.get_legend()
        if leg is not None and leg.get_visible():
            box = leg.get_window_extent(renderer)
            inside = ax.get_window_extent(renderer)
            for line in ax.get_lines():
                pts = line.get_transform().transform(line.get_xydata())
                hits = ((pts[:, 0] > box.x0) & (pts[:, 0] < box.x1) & (pts[:, 1] > box.y0) & (pts[:, 1] < box.y1)
                        & (pts[:, 0] > inside.x0) & (pts[:, 0] < inside.x1))
                if hits.any():
                    problems.append(f"panel {i}: the legend covers data of {line.get_label()!r}")
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
