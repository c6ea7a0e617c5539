"""The one rounding of a scale's ratio to a power of 1000 (`gma_ffc.unit_slips`), which the drive's
`unit_slip`, identify's `scale_mismatch` and diagnose's `displacement_scale_words` share."""

from __future__ import annotations

import math

from hypothesis import assume, given
from hypothesis import strategies as st

from gma_ffc.unit_slips import thousands_exponent, unit_slip_factor

RATIOS = st.floats(min_value=1e-15, max_value=1e15, allow_nan=False, allow_infinity=False)
POWERS = st.integers(min_value=-5, max_value=5)
OFF_A_POWER = st.floats(min_value=-1.45, max_value=1.45)     # decades off a power of 1000, short of halfway


@given(RATIOS)
def test_the_exponent_is_a_multiple_of_3_within_half_a_step_of_the_ratio(ratio):
    exponent = thousands_exponent(ratio)
    assert isinstance(exponent, int) and exponent % 3 == 0
    assert abs(math.log10(ratio) - exponent) <= 1.5 + 1e-9


@given(POWERS, OFF_A_POWER)
def test_a_ratio_near_a_power_of_1000_rounds_to_it(power, decades_off):
    assert thousands_exponent(10.0 ** (3 * power + decades_off)) == 3 * power


@given(RATIOS)
def test_the_inverse_ratio_rounds_to_the_inverse_power(ratio):
    assume(abs(abs(math.log10(ratio)) % 3 - 1.5) > 1e-6)      # not at a tie between two powers
    assert thousands_exponent(1.0 / ratio) == -thousands_exponent(ratio)


@given(RATIOS)
def test_a_slip_factor_only_two_decades_or_more_off_and_then_the_nearest_power(ratio):
    factor = unit_slip_factor(ratio)
    if abs(math.log10(ratio)) < 2:
        assert factor is None
    else:
        assert factor == 10.0 ** thousands_exponent(ratio) and factor != 1.0
        assert 10 ** -1.5 <= ratio / factor <= 10 ** 1.5 * (1 + 1e-12)


def test_the_slips_a_logger_makes():
    assert unit_slip_factor(1000.0) == 1000.0 and unit_slip_factor(0.001) == 0.001      # mm, nm under um
    assert unit_slip_factor(2.0e6) == 1e6                                                # um under m
    assert unit_slip_factor(40.0) is None and unit_slip_factor(1 / 40.0) is None          # a range, not a unit
    assert thousands_exponent(40.0) == 3 and thousands_exponent(31.0) == 0               # the drive's 30x rule
