"""A drive column's name is its quantity and its unit, joined by the last underscore (docs/recordings.md)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from gma_ffc.drive import drive_quantity, drive_unit

WORD = st.text(alphabet="abcdefghijklmnopqrstuvwxyzAV_", min_size=1, max_size=12)
UNIT = st.text(alphabet="abcdefghijklmnopqrstuvwxyzAVm", min_size=1, max_size=4)


@given(WORD, UNIT)
def test_the_name_splits_at_its_last_underscore(quantity, unit):
    name = f"{quantity}_{unit}"
    assert (drive_quantity(name), drive_unit(name)) == (quantity, unit)


def test_the_columns_the_spec_names():
    assert (drive_quantity("current_A"), drive_unit("current_A")) == ("current", "A")
    assert (drive_quantity("coil_voltage_V"), drive_unit("coil_voltage_V")) == ("coil_voltage", "V")
