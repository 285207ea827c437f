"""Digitizer codec against the golden bytes of docs/protocols/digitizer.md, plus decoder properties."""

import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.digitizer import protocol as p

D1 = bytes.fromhex("80 B2 E6 0E 00 00 00 00")
D2 = bytes.fromhex("03 00 00 00 02 00 00 00")
D3 = bytes.fromhex("03 00 00 00 02 00 00 00 01 00 00 00 02 00 00 00")
D4 = bytes.fromhex("44 47 53 47 01 10 01 00 05 00 00 00 02 00 00 00"
                   "E8 03 00 00 00 00 00 00 C7 9B C5 3E 72 41 12 F3"
                   "01 00 FE FF")
D5 = bytes.fromhex("44 47 53 47 01 08 0E 04 00 00 00 00 01 00 00 00"
                   "00 00 00 00 00 00 00 00 16 94 AF 9C 31 37 FD DB"
                   "03 FD 7F")


def test_golden_control_payloads():
    assert p.enc_u64(250_000_000) == D1
    assert p.enc_read_segments(3, 2) == D2
    assert p.dec_read_segments(D2) == (3, 2)
    st_ = p.Status(p.State.DONE, segments_captured=2, overrange_count=1, segments_sent=2)
    assert p.encode_status(st_) == D3
    assert p.decode_status(D3) == st_


def test_golden_segment_int16_single_channel():
    enc = p.encode_segment(5, 1000, p.channel_mask(("beat",)), 16, 0, np.array([[1, -2]]))
    assert enc == D4
    h, s, used = p.decode_segment(D4)
    assert (h.index, h.trigger_time_ns, h.n_samples, h.bits, h.overrange) == (5, 1000, 2, 16, 0)
    assert h.trigger_time_s == pytest.approx(1e-6)
    assert used == len(D4) and s.dtype == np.int16 and s.tolist() == [[1, -2]]


def test_golden_segment_int8_iq_plus_mzi():
    mask = p.channel_mask(("beat_i", "beat_q", "mzi"))
    assert mask == 0x0E
    assert p.channels_of(mask) == ("beat_i", "beat_q", "mzi")
    enc = p.encode_segment(0, 0, mask, 8, 0b100, np.array([[3], [-3], [127]]))
    assert enc == D5
    h, s, _ = p.decode_segment(D5)
    assert s.dtype == np.int8 and s[:, 0].tolist() == [3, -3, 127]
    assert h.overrange == 0b100


def test_channel_mask_rules():
    assert p.channel_mask(("beat", "mzi")) == 0x09
    for bad in (("beat_i",), ("beat", "beat_i", "beat_q"), ("beat", "beat"), ("adc7",), ()):
        with pytest.raises(p.DigitizerProtocolError):
            p.channel_mask(bad)


def test_record_dtype_matches_wire_layout():
    rec = p.segment_dtype(2, 3, 16)
    assert rec.itemsize == p.segment_bytes(2, 3, 16) == 32 + 12
    raw = np.frombuffer(D4, dtype=p.segment_dtype(1, 2, 16))
    assert raw["index"][0] == 5 and raw["data"][0].tolist() == [[1, -2]]


def test_corrupted_payload_and_header_detected():
    bad = bytearray(D4)
    bad[-1] ^= 0x01
    with pytest.raises(p.DigitizerProtocolError, match="payload crc32"):
        p.decode_segment(bytes(bad))
    bad = bytearray(D4)
    bad[8] = 6  # index changed without fixing the header crc
    with pytest.raises(p.DigitizerProtocolError, match="header crc32"):
        p.decode_segment(bytes(bad))


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.binary(max_size=80))
def test_decoders_raise_only_protocol_errors(data):
    for fn in (p.decode_segment, p.decode_segment_header, p.decode_status, p.decode_config,
               p.dec_read_segments, p.dec_u32, p.dec_u64):
        try:
            fn(data)
        except p.DigitizerProtocolError as exc:
            assert exc.device == "digitizer" and exc.command == "decode"


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.integers(0, len(D4) - 1), st.integers(1, 255))
def test_any_single_byte_corruption_is_rejected(pos, flip):
    bad = bytearray(D4)
    bad[pos] ^= flip
    with pytest.raises(p.DigitizerProtocolError):
        p.decode_segment(bytes(bad))


@settings(max_examples=150, deadline=None, derandomize=True)
@given(st.binary(max_size=100), st.lists(st.integers(-32768, 32767), min_size=1, max_size=40),
       st.integers(1, 17))
def test_stream_parser_resynchronizes(garbage, samples, step):
    seg_a = p.encode_segment(7, 123, 0x01, 16, 0, np.array([samples]))
    seg_b = p.encode_segment(8, 456, 0x01, 16, 1, np.array([samples[::-1]]))
    damaged = bytearray(seg_a)
    damaged[-1] ^= 0xFF  # payload crc fails: must be dropped, not kill the stream
    stream = garbage + bytes(damaged) + garbage + seg_a + seg_b
    parser = p.SegmentStreamParser()
    out = []
    for k in range(0, len(stream), step):
        out += parser.feed(stream[k:k + step])
    assert [h.index for h, _ in out] == [7, 8]
    assert out[0][1].tolist() == [samples] and out[1][1].tolist() == [samples[::-1]]
    assert parser.crc_errors >= 1


def test_crc_is_standard_ieee():
    # the check value of CRC-32/ISO-HDLC for "123456789" is 0xCBF43926
    assert zlib.crc32(b"123456789") == 0xCBF43926


# docs/protocols/digitizer.md, D8 and D9 (hand-assembled)
D8 = bytes.fromhex("00 2D 31 01 00 00 00 00")
D9 = bytes.fromhex("00 E1 F5 05 00 00 00 00 F4 01 00 00 14 00 00 00"
                   "F4 01 00 00 09 10 0C 00 00 2D 31 01 00 00 00 00")


def test_golden_bandwidth_and_config_with_resolution():
    assert p.enc_u64(20_000_000) == D8
    cfg = p.Config(100_000_000, 500, 20, 500, 0x09, 16, resolution_bits=12, bandwidth_hz=20_000_000)
    assert p.encode_config(cfg) == D9 and p.decode_config(D9) == cfg
    assert len(D9) == p.CONFIG_LEN == 32
    assert p.Config(1, 1, 1, 10, 1, 8).resolution_bits == 8  # default: the format's own bits
    for res, fmt in [(13, 8), (7, 16), (17, 16)]:
        bad = bytearray(D9)
        bad[21], bad[22] = fmt, res
        with pytest.raises(p.DigitizerProtocolError, match="resolution"):
            p.decode_config(bytes(bad))


D11 = bytes.fromhex("44 47 53 47 01 10 29 04 09 00 00 00 01 00 00 00"
                    "C0 C6 2D 00 00 00 00 00 2E 0F 9C 6D 8A 25 DF 96"
                    "64 00 D0 07 30 F8")


def test_golden_segment_quadrature_monitor_channel():
    """Bit 5 = mzi_q (issue 15), payload after beat and mzi (ascending bit order)."""
    mask = p.channel_mask(("beat", "mzi", "mzi_q"))
    assert mask == 0x29
    assert p.channels_of(mask) == ("beat", "mzi", "mzi_q")
    assert p.encode_segment(9, 3_000_000, mask, 16, 0b100, np.array([[100], [2000], [-2000]])) == D11
    h, s, _ = p.decode_segment(D11)
    assert s[:, 0].tolist() == [100, 2000, -2000] and h.overrange == 0b100 and h.channel_mask == 0x29


def test_quadrature_monitor_channel_needs_its_in_phase_channel():
    with pytest.raises(p.DigitizerProtocolError, match="mzi_q"):
        p.channel_mask(("beat", "mzi_q"))
    with pytest.raises(p.DigitizerProtocolError):
        p.validate_mask(0x40)     # bit 6 is still undefined
