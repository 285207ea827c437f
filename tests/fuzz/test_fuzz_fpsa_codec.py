"""Fuzz the FPSA link codec's payload decoders and the simulated FPGA's request handling.

tests/drivers/fpsa covers COBS, the frame parser and CRC corruption; this file covers what those
do not: every payload decoder (ACK/NAK responses, SET_PIXEL, pattern begin/chunk, pixel pairs,
Timing/Identity/Status blocks) on arbitrary bytes, and the byte-level peer (sim_devices.fpsa.device):
whatever well-framed command with whatever payload the host sends, the device answers with one
ACK or NAK frame for that sequence number and never raises (docs/protocols/fpsa.md).
"""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.fpsa import protocol as p
from drivers.errors import ProtocolError
from sim_devices.clock import VirtualClock
from sim_devices.fpsa.device import FpgaConfig, FpgaSim

FUZZ = settings(max_examples=300, derandomize=True, deadline=None)

PAYLOAD_DECODERS = [p.decode_set_pixel, p.unpack_pixels, p.decode_pattern_begin, p.decode_pattern_chunk,
                    p.Timing.unpack, p.Identity.unpack, p.Status.unpack, p.decode_inner, p.decode_frame,
                    p.cobs_decode]


@FUZZ
@given(data=st.binary(max_size=96), which=st.sampled_from(PAYLOAD_DECODERS))
def test_payload_decoders_raise_only_protocol_errors(data, which):
    try:
        which(data)
    except ProtocolError as exc:
        assert exc.device == "fpsa" and exc.command  # the shared driver error tree's context


@FUZZ
@given(seq=st.integers(0, 255), cmd=st.integers(0, 255), payload=st.binary(max_size=24))
def test_decode_response_of_any_frame_is_a_response_or_protocol_error(seq, cmd, payload):
    try:
        r = p.decode_response(p.Frame(seq, cmd, payload))
    except ProtocolError:
        # refused exactly when it is not a well-formed ACK/NAK (spec: docs/protocols/fpsa.md)
        known_codes = {int(c) for c in p.NakCode}
        assert (cmd not in (p.Cmd.ACK, p.Cmd.NAK)
                or (cmd == p.Cmd.ACK and len(payload) == 0)
                or (cmd == p.Cmd.NAK and (len(payload) != 6 or payload[1] not in known_codes)))
        return
    assert cmd in (p.Cmd.ACK, p.Cmd.NAK) and r.seq == seq
    assert r.ok == (cmd == p.Cmd.ACK)


@FUZZ
@given(pairs=st.lists(st.tuples(st.integers(0, 255), st.integers(0, 255)), max_size=40))
def test_pixel_pairs_roundtrip(pairs):
    arr = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    assert np.array_equal(p.unpack_pixels(p.pack_pixels(arr)), arr)


def _fresh_fpga():
    return FpgaSim(VirtualClock(), FpgaConfig(rows=20, cols=20, bonded_rows=tuple(range(20))))


@settings(max_examples=200, derandomize=True, deadline=None)
@given(requests=st.lists(st.tuples(st.integers(0, 255), st.integers(0, 255), st.binary(max_size=40)),
                         min_size=1, max_size=6))
def test_sim_fpga_answers_every_framed_request_with_ack_or_nak(requests):
    fpga = _fresh_fpga()
    for seq, cmd, payload in requests:
        out = fpga.feed(p.encode_frame(seq, cmd, payload))
        parser = p.FrameParser()
        frames = parser.feed(out)
        assert parser.pop_errors() == []
        assert len(frames) == 1, (cmd, payload, out)
        r = p.decode_response(frames[0])
        assert r.seq == seq and r.request_cmd == cmd


@settings(max_examples=200, derandomize=True, deadline=None)
@given(noise=st.binary(max_size=200))
def test_sim_fpga_survives_raw_noise_then_serves_a_clean_request(noise):
    fpga = _fresh_fpga()
    out = fpga.feed(noise)
    parser = p.FrameParser()
    for f in parser.feed(out):  # whatever it answered to the noise is well-formed
        p.decode_response(f)
    assert parser.pop_errors() == []
    # the link recovers: a delimiter ends any partial frame, then IDENTIFY is answered
    fpga.feed(b"\x00")
    seq = 7 if not noise else (noise[0] + 1) % 256
    frames = p.FrameParser().feed(fpga.feed(p.encode_frame(seq, p.Cmd.IDENTIFY)))
    assert len(frames) == 1
    r = p.decode_response(frames[0])
    assert r.ok and r.seq == seq and r.request_cmd == p.Cmd.IDENTIFY
