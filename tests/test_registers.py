"""The register-map codec: round trips for every type and order, reference words, validation."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gma_ffc.errors import ConfigError
from gma_ffc.registers import TYPES, Channel, RegisterMap, load_register_map

ORDERS = ("big", "little")
INT_TYPES = ("int16", "uint16", "int32", "uint32")


def channel(type_: str, word_order: str = "big", byte_order: str = "big", scale: float = 1.0,
            offset: float = 0.0) -> Channel:
    return RegisterMap.from_dict(
        {"channels": {"x": {"function": "holding", "address": 0, "type": type_, "word_order": word_order,
                            "byte_order": byte_order, "scale": scale, "offset": offset, "access": "rw"}}}
    )["x"]


@pytest.mark.parametrize("type_", INT_TYPES)
@pytest.mark.parametrize("word_order", ORDERS)
@pytest.mark.parametrize("byte_order", ORDERS)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_integer_round_trip_every_type_and_order(type_, word_order, byte_order, data):
    _, count, lo, hi = TYPES[type_]
    scale = data.draw(st.sampled_from([1.0, 0.001, 0.25, -2.0]))
    offset = data.draw(st.sampled_from([0.0, -5.0, 100.0]))
    ch = channel(type_, word_order, byte_order, scale, offset)
    raw = data.draw(st.integers(int(lo), int(hi)))
    physical = raw * scale + offset
    words = ch.encode(physical)
    assert len(words) == count
    assert all(0 <= w <= 0xFFFF for w in words)
    assert ch.decode(words) == pytest.approx(physical, rel=1e-12, abs=abs(scale) * 1e-6)
    # words -> value -> words is the identity as well
    assert ch.encode(ch.decode(words)) == words


@pytest.mark.parametrize("word_order", ORDERS)
@pytest.mark.parametrize("byte_order", ORDERS)
@settings(max_examples=80, deadline=None)
@given(value=st.floats(width=32, allow_nan=False, allow_infinity=True))
def test_float32_round_trip_exact(word_order, byte_order, value):
    ch = channel("float32", word_order, byte_order)
    assert ch.decode(ch.encode(value)) == value


@pytest.mark.parametrize("word_order", ORDERS)
@pytest.mark.parametrize("byte_order", ORDERS)
@settings(max_examples=80, deadline=None)
@given(words=st.lists(st.integers(0, 0xFFFF), min_size=2, max_size=2))
def test_float32_words_round_trip(word_order, byte_order, words):
    ch = channel("float32", word_order, byte_order)
    value = ch.decode(words)
    if math.isnan(value):  # NaN payloads are not preserved through a Python float; NaN stays NaN
        assert math.isnan(ch.decode(ch.encode(value)))
    else:
        assert ch.encode(value) == words


def test_nan_encodes_as_float32_nan_only():
    assert math.isnan(channel("float32").decode(channel("float32").encode(float("nan"))))
    with pytest.raises(ConfigError, match="'x'.*'value'"):
        channel("int16").encode(float("nan"))


@pytest.mark.parametrize(
    "type_, word_order, byte_order, value, expected",
    [
        # Reference layouts as device manuals print them (struct gives the big-endian bytes).
        ("float32", "big", "big", 1.0, [0x3F80, 0x0000]),
        ("float32", "little", "big", 1.0, [0x0000, 0x3F80]),
        ("float32", "big", "little", 1.0, [0x803F, 0x0000]),
        ("float32", "little", "little", 1.0, [0x0000, 0x803F]),
        ("int32", "big", "big", 0x12345678, [0x1234, 0x5678]),
        ("int32", "little", "big", 0x12345678, [0x5678, 0x1234]),
        ("int32", "big", "big", -2, [0xFFFF, 0xFFFE]),
        ("uint32", "little", "little", 0x01020304, [0x0403, 0x0201]),
        ("int16", "big", "big", -1, [0xFFFF]),
        ("int16", "big", "little", 0x0102, [0x0201]),
        ("uint16", "big", "big", 65535, [0xFFFF]),
    ],
)
def test_reference_word_layouts(type_, word_order, byte_order, value, expected):
    ch = channel(type_, word_order, byte_order)
    assert ch.encode(value) == expected
    assert ch.decode(expected) == pytest.approx(value)


def test_scale_and_offset_apply_physical_equals_raw_times_scale_plus_offset():
    ch = channel("int16", scale=0.001, offset=-1.0)
    assert ch.encode(0.25) == [1250]
    assert ch.decode([struct.unpack(">H", struct.pack(">h", -500))[0]]) == pytest.approx(-1.5)


@pytest.mark.parametrize(
    "type_, value",
    [("int16", 32768), ("int16", -32769), ("uint16", -1), ("uint16", 65536), ("int32", 2**31),
     ("uint32", -1), ("float32", 1e39)],
)
def test_out_of_range_encoding_names_channel(type_, value):
    with pytest.raises(ConfigError, match=r"channel 'x', key 'value'.*range"):
        channel(type_).encode(value)


def test_coil_bits():
    m = RegisterMap.from_dict({"channels": {"output_enable": {"function": "coil", "address": 3, "access": "rw"}}})
    ch = m["output_enable"]
    assert ch.is_bit and ch.count == 1
    assert ch.encode(True) == [1] and ch.encode(0) == [0]
    assert ch.decode([True]) is True and ch.decode([0]) is False
    with pytest.raises(ConfigError, match="output_enable"):
        ch.encode(2)


BAD_MAPS = [
    ({"channels": {"a": {"function": "holding", "address": 0, "type": "int64"}}}, "'a', key 'type'"),
    ({"channels": {"a": {"function": "register", "address": 0}}}, "'a', key 'function'"),
    ({"channels": {"a": {"function": "holding"}}}, "'a', key 'address': missing"),
    ({"channels": {"a": {"function": "holding", "address": -1}}}, "'a', key 'address'"),
    ({"channels": {"a": {"function": "holding", "address": 65535, "type": "float32"}}}, "'a', key 'address'"),
    ({"channels": {"a": {"function": "holding", "address": 0, "word_order": "middle"}}}, "'a', key 'word_order'"),
    ({"channels": {"a": {"function": "holding", "address": 0, "byte_order": 1}}}, "'a', key 'byte_order'"),
    ({"channels": {"a": {"function": "holding", "address": 0, "scale": 0}}}, "'a', key 'scale'"),
    ({"channels": {"a": {"function": "holding", "address": 0, "offset": "x"}}}, "'a', key 'offset'"),
    ({"channels": {"a": {"function": "holding", "address": 0, "unit_id": 300}}}, "'a', key 'unit_id'"),
    ({"channels": {"a": {"function": "input", "address": 0, "access": "rw"}}}, "'a', key 'access'"),
    ({"channels": {"a": {"function": "holding", "address": 0, "access": "w"}}}, "'a', key 'access'"),
    ({"channels": {"a": {"function": "coil", "address": 0, "type": "int16"}}}, "'a', key 'type'"),
    ({"channels": {"a": {"function": "holding", "address": 0, "colour": 1}}}, "'a', key 'colour'"),
    ({"channels": {"a": {"function": "holding", "address": 0, "type": "float32"},
                   "b": {"function": "holding", "address": 1}}}, "'b', key 'address'.*overlaps channel 'a'"),
    ({"channels": {}}, "'channels'"),
    ({"chanels": {}}, "chanels"),
    ({"defaults": {"address": 1}, "channels": {"a": {"function": "coil", "address": 0}}}, "defaults.address"),
    ([1, 2], "mapping"),
]


@pytest.mark.parametrize("data, message", BAD_MAPS)
def test_validation_names_channel_and_key(data, message):
    with pytest.raises(ConfigError, match=message):
        RegisterMap.from_dict(data)


def test_same_address_on_different_units_or_tables_is_fine_and_defaults_apply():
    m = RegisterMap.from_dict({
        "defaults": {"word_order": "little", "unit_id": 2},
        "channels": {
            "a": {"function": "holding", "address": 0, "type": "float32"},
            "b": {"function": "holding", "address": 0, "type": "float32", "unit_id": 3},
            "c": {"function": "input", "address": 0, "type": "float32"},
        },
    })
    assert m["a"].word_order == "little" and m["a"].unit_id == 2
    assert m["b"].unit_id == 3
    assert m.unit_ids == (2, 3)


def test_read_plan_groups_adjacent_channels_and_decodes_blocks():
    m = RegisterMap.from_dict({"channels": {
        "current_A": {"function": "input", "address": 0, "type": "int16", "scale": 0.001},
        "force_N": {"function": "input", "address": 1, "type": "float32"},
        "displacement_um": {"function": "input", "address": 10, "type": "int32", "scale": 0.01},
        "output_enable": {"function": "coil", "address": 0, "access": "rw"},
        "remote": {"function": "input", "address": 0, "type": "uint16", "unit_id": 2},
    }})
    plan = m.read_plan()
    spans = [(b.unit_id, b.function, b.address, b.count, [c.name for c in b.channels]) for b in plan]
    assert (1, "input", 0, 3, ["current_A", "force_N"]) in spans
    assert (1, "input", 10, 2, ["displacement_um"]) in spans
    assert (1, "coil", 0, 1, ["output_enable"]) in spans
    assert (2, "input", 0, 1, ["remote"]) in spans
    assert len(plan) == 4
    # with a gap allowance the two input blocks on unit 1 merge
    merged = [b for b in m.read_plan(max_gap=10) if b.unit_id == 1 and b.function == "input"]
    assert len(merged) == 1 and merged[0].count == 12
    words = m.encode("current_A", 1.5) + m.encode("force_N", -42.5)
    values = plan[[s[4] for s in spans].index(["current_A", "force_N"])].decode(words)
    assert values == {"current_A": pytest.approx(1.5), "force_N": -42.5}


def test_require_and_unknown_channel():
    m = RegisterMap.from_dict({"channels": {"current_A": {"function": "input", "address": 0}}})
    with pytest.raises(ConfigError, match="no channel 'force_N'"):
        m.require("force_N")
    with pytest.raises(ConfigError, match="'current_A', key 'access'"):
        m.require(writable=["current_A"])


def test_to_dict_round_trip():
    m = RegisterMap.from_dict({"channels": {
        "current_setpoint_A": {"function": "holding", "address": 4, "type": "int32", "scale": 1e-4,
                               "word_order": "little", "access": "rw", "unit_id": 5},
        "output_enable": {"function": "coil", "address": 0, "access": "rw"},
    }})
    assert RegisterMap.from_dict(m.to_dict()) == m


def test_yaml_loading(tmp_path):
    path = tmp_path / "map.yaml"
    path.write_text("channels:\n  force_N: {function: input, address: 2, type: float32, word_order: little}\n")
    assert load_register_map(path)["force_N"].word_order == "little"
    path.write_text("channels:\n  current_A: {function: input, address: 0, type: int32, scale: 1e-6}\n")
    assert load_register_map(path)["current_A"].scale == 1e-6  # YAML 1.1 reads 1e-6 as a string
    path.write_text("channels: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_register_map(path)
    with pytest.raises(ConfigError, match="cannot read"):
        load_register_map(tmp_path / "missing.yaml")
