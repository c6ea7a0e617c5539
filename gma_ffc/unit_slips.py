"""How far a ratio of two scales is off by a unit: the power of 1000 nearest it, the step between
the metric prefixes a logger slips by (a displacement in mm or nm under displacement_um, a drive in
mA under current_A). The drive, identify and diagnose each judge a recording's scale by it.
Pure maths."""

from __future__ import annotations

import numpy as np

UNIT_STEP_DECADES = 3      # milli, micro, nano, kilo: the prefixes a logger slips by are 1000 apart
UNIT_SLIP_DECADES = 2      # a ratio 100x or more off 1 is a unit's power of 1000; nearer 1 (30x to 100x) it is
                           # as likely a range, a gain or another actuator, and no power of 1000 converts it


def thousands_exponent(ratio: float) -> int:
    """The decimal exponent of the power of 1000 nearest `ratio` on a log scale, a multiple of 3:
    3 for ratios from about 32x to 32,000x, -3 for their inverses, 0 within about 32x of 1."""
    return UNIT_STEP_DECADES * round(float(np.log10(ratio)) / UNIT_STEP_DECADES)


def unit_slip_factor(ratio: float) -> float | None:
    """The power of 1000 nearest `ratio` (1000.0, 0.001, 1e6, ...) when `ratio` is 100x or more off
    1 (`UNIT_SLIP_DECADES`), else None: what a scale that far off is to be divided by."""
    if abs(float(np.log10(ratio))) < UNIT_SLIP_DECADES:
        return None
    return 10.0 ** thousands_exponent(ratio)
