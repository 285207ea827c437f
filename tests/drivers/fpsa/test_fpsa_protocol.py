"""Codec tests: golden vectors from docs/protocols/fpsa.md, COBS/CRC properties, parser resync."""

from __future__ import annotations

import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.fpsa import protocol as p
from drivers.errors import CrcError, FramingError, LengthError, PayloadError, ProtocolError

DOC = Path(__file__).resolve().parents[3] / "docs" / "protocols" / "fpsa.md"


def golden_vectors() -> dict[str, tuple[int, int, bytes, bytes]]:
    text = DOC.read_text()
    block = re.search(r"```golden\n(.*?)```", text, re.S).group(1)
    out = {}
    for line in block.strip().splitlines():
        name, seq, cmd, payload, wire = (f.strip() for f in line.split("|"))
        out[name] = (int(seq, 16), int(cmd, 16), bytes.fromhex(payload), bytes.fromhex(wire))
    return out


GOLDEN = golden_vectors()


def test_golden_block_is_complete():
    assert len(GOLDEN) >= 10
    assert {"identify_req", "set_pixel_req", "nak_unbonded", "status_ack"} <= GOLDEN.keys()


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_golden_encode_and_decode(name):
    seq, cmd, payload, wire = GOLDEN[name]
    assert p.encode_frame(seq, cmd, payload) == wire
    assert p.decode_frame(wire) == p.Frame(seq, cmd, payload)


def test_golden_payload_builders_match_doc():
    assert GOLDEN["set_pixel_req"][2] == p.encode_set_pixel(5, 64)
    assert GOLDEN["set_timing_req"][2] == p.Timing(8000, 0, 1, 80000).pack()
    assert GOLDEN["set_timing_req"][2] == p.DEFAULT_TIMING.pack()
    two = np.array([[0, 0], [1, 5]])
    assert GOLDEN["pattern_begin_req"][2] == p.encode_pattern_begin(2, p.crc32(p.pack_pixels(two)))
    assert GOLDEN["pattern_chunk_req"][2] == p.encode_pattern_chunk(0, p.pack_pixels(two))
    seq, cmd, payload, wire = GOLDEN["nak_unbonded"]
    assert p.encode_nak(seq, p.Cmd.PATTERN_CHUNK, p.NakCode.BAD_ROW_UNBONDED, 3) == wire
    r = p.decode_response(p.decode_frame(wire))
    assert (r.ok, r.request_cmd, r.code, r.detail) == (False, 0x11, p.NakCode.BAD_ROW_UNBONDED, 3)
    st_ = p.Status.unpack(p.decode_response(p.decode_frame(GOLDEN["status_ack"][3])).data)
    assert st_ == p.Status(p.State.RUNNING, p.FaultFlag.NONE, 258, 258, 773)


def test_crc16_check_value_and_crc32_reference():
    # published check values of the two CRC catalogue entries
    assert p.crc16_ccitt_false(b"123456789") == 0x29B1
    assert p.crc32(b"123456789") == 0xCBF43926
    assert p.crc32(bytes([0, 0, 1, 5])) == 0x48351AD2 == zlib.crc32(bytes([0, 0, 1, 5]))


def test_cobs_known_examples():
    # examples from Cheshire & Baker / the Wikipedia COBS table
    assert p.cobs_encode(b"\x00") == b"\x01\x01"
    assert p.cobs_encode(b"\x00\x00") == b"\x01\x01\x01"
    assert p.cobs_encode(b"\x11\x22\x00\x33") == b"\x03\x11\x22\x02\x33"
    assert p.cobs_encode(b"\x11\x00\x00\x00") == b"\x02\x11\x01\x01\x01"
    run = bytes(range(1, 255))  # 254 non-zero bytes
    enc = p.cobs_encode(run)
    # canonical COBS: a full 254-byte block ends the frame with no empty block after it
    assert enc == b"\xff" + run and p.cobs_decode(enc) == run
    # a sender that adds the redundant empty block is still understood
    assert p.cobs_decode(enc + b"\x01") == run
    for bad in (b"\x05\x01", b"\x03\x00\x01", b"\x00"):
        with pytest.raises(FramingError):
            p.cobs_decode(bad)


@given(st.binary(max_size=1200))
@settings(derandomize=True)
def test_cobs_roundtrip_and_no_zero(data):
    enc = p.cobs_encode(data)
    assert 0 not in enc
    assert len(enc) <= len(data) + len(data) // 254 + 1
    assert p.cobs_decode(enc) == data


@given(st.integers(0, 255), st.integers(0, 255), st.binary(max_size=p.MAX_PAYLOAD))
@settings(max_examples=60, derandomize=True)
def test_frame_roundtrip(seq, cmd, payload):
    wire = p.encode_frame(seq, cmd, payload)
    assert wire.endswith(b"\x00") and wire.count(0) == 1
    assert p.FrameParser().feed(wire) == [p.Frame(seq, cmd, payload)]


@given(st.lists(st.binary(max_size=300), max_size=8))
@settings(max_examples=200, derandomize=True)
def test_parser_random_bytes_only_protocol_errors(chunks):
    parser = p.FrameParser()
    for c in chunks:
        for item in parser.feed_all(c):
            assert isinstance(item, (p.Frame, ProtocolError))


@given(st.binary(max_size=400), st.integers(0, 255), st.binary(max_size=64),
       st.lists(st.integers(1, 50), max_size=6))
@settings(max_examples=200, derandomize=True)
def test_parser_resyncs_after_garbage_split_anywhere(garbage, seq, payload, cuts):
    good = p.encode_frame(seq, p.Cmd.SET_PIXEL, payload)
    stream = garbage + b"\x00" + good  # the garbage is terminated; the next frame must decode
    parser = p.FrameParser()
    frames: list[p.Frame] = []
    pos = 0
    for c in cuts:
        frames += parser.feed(stream[pos:pos + c])
        pos += c
    frames += parser.feed(stream[pos:])
    assert frames[-1] == p.Frame(seq, p.Cmd.SET_PIXEL, payload)


@given(st.integers(0, 255), st.binary(min_size=0, max_size=40), st.data())
@settings(max_examples=200, derandomize=True)
def test_corrupted_frame_is_rejected_or_detected(seq, payload, data):
    wire = bytearray(p.encode_frame(seq, p.Cmd.PATTERN_CHUNK, payload))
    i = data.draw(st.integers(0, len(wire) - 2))
    flip = data.draw(st.integers(1, 255))
    wire[i] ^= flip
    parser = p.FrameParser()
    items = parser.feed_all(bytes(wire) + p.encode_frame(1, p.Cmd.STATUS))
    good = [x for x in items if isinstance(x, p.Frame)]
    # a single-byte error is always caught by COBS structure or CRC-16 (Hamming distance 4)
    assert p.Frame(seq, p.Cmd.PATTERN_CHUNK, payload) not in good
    assert good[-1] == p.Frame(1, p.Cmd.STATUS, b"")
    assert all(isinstance(x, ProtocolError) for x in items if not isinstance(x, p.Frame))


def test_parser_error_types():
    parser = p.FrameParser()
    inner = bytearray(p.encode_inner(7, 0x24, b""))
    inner[-1] ^= 0x01
    items = parser.feed_all(p.cobs_encode(bytes(inner)) + b"\x00")
    assert isinstance(items[0], CrcError) and items[0].seq == 7 and items[0].cmd == 0x24
    # header says 5 bytes, only 0 present (CRC recomputed so only the length is wrong)
    body = struct.pack("<BBH", 1, 2, 5)
    bad_len = body + struct.pack("<H", p.crc16_ccitt_false(body))
    assert isinstance(parser.feed_all(p.cobs_encode(bad_len) + b"\x00")[0], LengthError)
    assert isinstance(parser.feed_all(b"\x05\x01\x00")[0], FramingError)  # block overruns
    assert isinstance(parser.feed_all(b"\x02\x01\x00")[0], LengthError)  # too short
    assert parser.error_count == 4 and len(parser.pop_errors()) == 4 and parser.errors == []


def test_parser_overrun_discards_until_next_delimiter():
    parser = p.FrameParser(max_encoded_len=32)
    items = parser.feed_all(b"\x07" * 100)
    assert len(items) == 1 and isinstance(items[0], FramingError)
    # the tail of the over-long frame is dropped silently, then decoding resumes
    assert parser.feed(b"\x07" * 10 + b"\x00" + p.encode_frame(3, 0x01)) == [p.Frame(3, 0x01)]


def test_empty_frames_ignored():
    assert p.FrameParser().feed_all(b"\x00\x00\x00") == []


def test_payload_codecs_roundtrip_and_length_checks():
    ident = p.Identity("Caltech", "FPSA128", (1, 2, 3), 128, 128,
                       tuple(r for r in range(128) if r % 4 != 3))
    back = p.Identity.unpack(ident.pack())
    assert back == ident and len(back.bonded_rows) == 96
    assert len(ident.pack()) == 16 + 16 + 3 + 2 + 2 + 16
    stt = p.Status(p.State.DONE, p.FaultFlag.MULTI_ROW | p.FaultFlag.LINK_ERRORS, 5, 6, 7)
    assert p.Status.unpack(stt.pack()) == stt
    tm = p.Timing(1, 2, 3, 4)
    assert p.Timing.unpack(tm.pack()) == tm
    with pytest.raises(LengthError):
        p.Timing.unpack(b"\x00" * 13)
    with pytest.raises(LengthError):
        p.decode_set_pixel(b"\x01")
    with pytest.raises(LengthError):
        p.decode_pattern_chunk(b"\x00" * 7)
    with pytest.raises(PayloadError):
        p.Status.unpack(bytes([9]) + b"\x00" * 12)
    with pytest.raises(PayloadError):
        p.Timing(triggers_per_pixel=70000).pack()
    with pytest.raises(LengthError):
        p.encode_frame(0, 1, bytes(p.MAX_PAYLOAD + 1))
    chunk = p.decode_pattern_chunk(p.encode_pattern_chunk(12, bytes([1, 2, 3, 4])))
    assert (chunk.offset, chunk.count, chunk.crc32) == (12, 2, zlib.crc32(bytes([1, 2, 3, 4])))


def test_pack_pixels_layout():
    px = np.array([[3, 4], [5, 6]])
    assert p.pack_pixels(px) == bytes([3, 4, 5, 6])
    np.testing.assert_array_equal(p.unpack_pixels(bytes([3, 4, 5, 6])), px)
    with pytest.raises(PayloadError):
        p.pack_pixels(np.array([[0, 256]]))
    with pytest.raises(PayloadError):
        p.pack_pixels(np.zeros((3,)))


def test_wire_time_is_ten_bits_per_byte():
    assert p.wire_time_s(300, 3_000_000) == pytest.approx(1e-3)
