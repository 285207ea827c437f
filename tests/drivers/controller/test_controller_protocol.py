"""Pure tests of the controller register map, scaling, limits and decoders (no sockets)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.controller import protocol as p
from drivers.controller.errors import ConfigError, LimitError
from drivers.errors import ProtocolError

SCALED = [p.LASER_CURRENT_SETPOINT, p.TEC_SETPOINT, p.HV_SETPOINT,
          p.LASER_CURRENT, p.TEC_TEMPERATURE, p.HV_VOLTAGE]


# --- map layout ---------------------------------------------------------------------------------
@pytest.mark.parametrize("table", list(p.Table))
def test_each_table_is_contiguous_from_zero_without_overlap(table):
    spans = sorted((r.address, r.address + r.words) for r in p.REGISTER_MAP if r.table is table)
    assert spans[0][0] == 0
    for (_, end), (start, _) in zip(spans, spans[1:]):
        assert start == end, f"{table}: gap or overlap at {end}..{start}"
    assert p.table_size(table) == spans[-1][1]


def test_blocks_cover_the_registers_they_claim():
    assert p.IDENTITY_BLOCK == (0, 6)      # IR 0..5
    assert p.STATUS_BLOCK == (6, 7)        # IR 6..12
    assert p.FLAGS_BLOCK == (0, 5)         # DI 0..4
    assert p.register_at(p.Table.INPUT, 11) is p.UPTIME_MS
    assert p.register_at(p.Table.INPUT, 13) is None


# --- scaling, vectors written by hand in docs/protocols/controller.md ---------------------------
@pytest.mark.parametrize(
    "reg, value, word",
    [
        (p.TEC_SETPOINT, -5.00, 0xFE0C),
        (p.HV_SETPOINT, 50.00, 0x1388),   # 128x128 FPSA actuation, §4.3
        (p.HV_SETPOINT, 32.00, 0x0C80),   # 20x20 FPSA pull-in, §4.2.6
        (p.LASER_CURRENT_SETPOINT, 655.35, 0xFFFF),
        (p.LASER_CURRENT_SETPOINT, 120.00, 0x2EE0),
        (p.TEC_SETPOINT, 25.00, 0x09C4),
    ],
)
def test_scaling_matches_hand_vectors(reg, value, word):
    assert p.encode_value(reg, value) == [word]
    assert p.decode_value(reg, [word]) == pytest.approx(value, abs=1e-9)


def test_scaling_rounds_to_nearest_lsb():
    assert p.encode_value(p.HV_SETPOINT, 32.004) == [3200]
    assert p.encode_value(p.HV_SETPOINT, 32.006) == [3201]


@pytest.mark.parametrize("value", [655.36, -0.01, math.nan, math.inf, "12", None, True])
def test_unencodable_laser_current_is_a_limit_error(value):
    with pytest.raises(LimitError) as ei:
        p.encode_value(p.LASER_CURRENT_SETPOINT, value)
    assert "LASER_CURRENT_SETPOINT" in str(ei.value)


def test_u32_is_high_word_first_and_ascii_is_big_endian():
    assert p.encode_value(p.UPTIME_MS, 0x0001_0002) == [0x0001, 0x0002]
    assert p.decode_value(p.UPTIME_MS, [0xFFFF, 0xFFFF]) == 2**32 - 1
    assert p.encode_value(p.MODEL, "LHV-1550") == [0x4C48, 0x562D, 0x3135, 0x3530]
    assert p.decode_value(p.MODEL, [0x4142, 0x4300, 0, 0]) == "ABC"
    with pytest.raises(ProtocolError):
        p.encode_value(p.MODEL, "TOO-LONG-NAME")


# --- limits -------------------------------------------------------------------------------------
def test_limit_error_names_quantity_value_and_range():
    lim = p.Limits(max_laser_current_ma=200.0, max_hv_v=60.0, tec_range_c=(18.0, 35.0))
    with pytest.raises(LimitError) as ei:
        lim.check(p.HV_SETPOINT, 70.0)
    msg = str(ei.value)
    assert "HV_SETPOINT" in msg and "70.0" in msg and "[0, 60]" in msg
    assert (ei.value.low, ei.value.high, ei.value.unit) == (0.0, 60.0, "V")
    with pytest.raises(LimitError, match=r"TEC_SETPOINT.*\[18, 35\]"):
        lim.check(p.TEC_SETPOINT, 17.99)
    assert lim.check(p.TEC_SETPOINT, 18.0) == 18.0
    assert lim.check(p.LASER_CURRENT_SETPOINT, 200) == 200.0


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(max_laser_current_ma=0.0, max_hv_v=60.0, tec_range_c=(18.0, 35.0)),
        dict(max_laser_current_ma=100.0, max_hv_v=-1.0, tec_range_c=(18.0, 35.0)),
        dict(max_laser_current_ma=100.0, max_hv_v=60.0, tec_range_c=(35.0, 18.0)),
        dict(max_laser_current_ma=math.nan, max_hv_v=60.0, tec_range_c=(18.0, 35.0)),
    ],
)
def test_inconsistent_limits_are_a_config_error(kwargs):
    with pytest.raises(ConfigError):
        p.Limits(**kwargs)


def test_hardware_limits_cover_both_fpsa_actuation_voltages():
    # 50 V (128x128, §4.3) and 32 V pull-in (20x20, §4.2.6) must be settable on the device.
    assert p.HARDWARE_LIMITS.check(p.HV_SETPOINT, 50.0) == 50.0
    assert p.HARDWARE_LIMITS.check(p.HV_SETPOINT, 32.0) == 32.0


# --- faults -------------------------------------------------------------------------------------
def test_fault_bits():
    assert p.decode_faults(0) == frozenset()
    assert p.decode_faults(0b1000) == {p.Fault.INTERLOCK_OPEN}
    assert p.decode_faults(0b10101) == {p.Fault.LASER_OVER_CURRENT, p.Fault.HV_FAULT, p.Fault.TEC_FAULT}
    assert p.encode_faults({p.Fault.OVER_TEMPERATURE, p.Fault.INTERLOCK_OPEN}) == 0b1010
    with pytest.raises(ProtocolError, match="undefined fault bits 0x0020"):
        p.decode_faults(0b100000)


# --- property tests -----------------------------------------------------------------------------
@st.composite
def scaled_value(draw):
    reg = draw(st.sampled_from(SCALED))
    lo, hi = reg.representable_range()
    return reg, draw(st.floats(min_value=lo, max_value=hi, allow_nan=False))


@settings(max_examples=300, deadline=None)
@given(scaled_value())
def test_scaling_round_trip_is_within_half_an_lsb(rv):
    reg, value = rv
    words = p.encode_value(reg, value)
    assert len(words) == 1 and 0 <= words[0] <= 0xFFFF
    back = p.decode_value(reg, words)
    assert abs(back - value) <= reg.scale / 2 + 1e-9


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(SCALED), st.integers(0, 0xFFFF))
def test_every_wire_word_decodes_and_re_encodes_exactly(reg, word):
    assert p.encode_value(reg, p.decode_value(reg, [word])) == [word]


_any_int = st.integers(min_value=-(2**20), max_value=2**20)


@settings(max_examples=300, deadline=None)
@given(st.lists(_any_int, min_size=0, max_size=10))
def test_status_decode_of_arbitrary_words_raises_only_protocol_error(words):
    try:
        status = p.decode_status(words)
    except ProtocolError:
        return
    assert len(words) == p.STATUS_BLOCK[1] and all(0 <= w <= 0xFFFF for w in words)
    assert status.faults == p.decode_faults(words[3])
    assert 0.0 <= status.laser_current_ma <= 655.35
    assert -327.68 <= status.tec_c <= 327.67


@settings(max_examples=300, deadline=None)
@given(st.lists(_any_int, min_size=0, max_size=8))
def test_identity_decode_of_arbitrary_words_raises_only_protocol_error(words):
    try:
        ident = p.decode_identity(words)
    except ProtocolError:
        return
    assert len(ident.model) <= 8 and ident.model.isprintable()


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(p.REGISTER_MAP), st.lists(_any_int, min_size=0, max_size=5))
def test_any_register_decode_raises_only_protocol_error(reg, words):
    try:
        p.decode_value(reg, words)
    except ProtocolError as exc:
        assert reg.name in str(exc)
