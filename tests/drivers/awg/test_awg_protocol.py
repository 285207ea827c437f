"""AWG codec: USBTMC framing and SCPI/IEEE-488.2 blocks against the golden bytes of docs/protocols/awg.md."""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from drivers import usbtmc
from drivers.awg import protocol as p
from drivers.errors import ProtocolError

G1 = bytes.fromhex("01 01 FE 00 06 00 00 00 01 00 00 00 2A 49 44 4E 3F 0A 00 00")
G2 = bytes.fromhex("02 02 FD 00 00 00 01 00 00 00 00 00")
G3 = bytes.fromhex("02 02 FD 00 02 00 00 00 01 00 00 00 31 0A 00 00")
G4 = bytes.fromhex("23 31 36 00 00 FF 7F 01 80")


def test_golden_msg_out_request_and_msg_in():
    assert usbtmc.encode_dev_dep_msg_out(1, b"*IDN?\n") == G1
    assert usbtmc.encode_request_dev_dep_msg_in(2, 65536) == G2
    assert usbtmc.encode_dev_dep_msg_in(2, b"1\n") == G3
    assert usbtmc.decode_dev_dep_msg_in(G3, 2) == (b"1\n", True)


def test_golden_block_and_upload_command():
    codes = np.array([0, 32767, -32767], dtype=np.int16)
    assert p.encode_block(p.encode_codes(codes)) == G4
    assert p.cmd_upload(codes) == b"SOUR:DATA:ARB " + G4
    payload, end = p.decode_block(G4)
    assert end == len(G4)
    assert np.array_equal(p.decode_codes(payload), codes)


def test_device_parser_decodes_golden_out_transfer():
    parser = usbtmc.UsbtmcOutParser()
    (hdr, payload), = parser.feed(G1)
    assert (hdr.msg_id, hdr.btag, hdr.transfer_size, hdr.eom) == (1, 1, 6, True)
    assert payload == b"*IDN?\n"
    (req, _), = parser.feed(G2)
    assert (req.msg_id, req.btag, req.transfer_size) == (2, 2, 65536)


def test_btag_sequence_skips_zero():
    assert usbtmc.next_btag(255) == 1
    assert usbtmc.next_btag(1) == 2
    with pytest.raises(usbtmc.UsbtmcProtocolError):
        usbtmc.encode_dev_dep_msg_out(0, b"x")


def test_msg_in_with_wrong_btag_is_rejected():
    with pytest.raises(usbtmc.UsbtmcProtocolError, match="bTag"):
        usbtmc.decode_dev_dep_msg_in(G3, 3)


def test_scpi_message_split_respects_block_containing_separators():
    payload = b";\n;#9"
    msg = b"*RST;SOUR:DATA:ARB " + p.encode_block(payload) + b";outp on\n"
    cmds = p.parse_message(msg)
    assert [c.header for c in cmds] == ["*RST", "SOUR:DATA:ARB", "OUTP"]
    assert cmds[1].args == (payload,)
    assert cmds[2].args == ("on",)


def test_long_forms_are_canonicalized():
    (c,) = p.parse_message(b":SOURce:FREQuency:SAMPle? \n")
    assert c.header == "SOUR:FREQ:SAMP" and c.query


def test_codes_from_normalized_full_scale_and_rounding():
    codes = p.codes_from_normalized(np.array([-1.0, 0.0, 1.0, 0.5]))
    assert codes.tolist() == [-32767, 0, 32767, 16384]  # 0.5*32767 = 16383.5 -> 16384
    with pytest.raises(ValueError):
        p.codes_from_normalized(np.array([1.5]))


def test_volts_transfer_function():
    v = p.volts_from_codes(np.array([32767, -32767, 0]), amplitude_v=0.5, offset_v=0.2)
    assert np.allclose(v, [0.7, -0.3, 0.2])


def test_reply_parsers():
    assert p.parse_error(b'-222,"Data out of range;SOUR:VOLT 9.0"\n') == (-222, "Data out of range;SOUR:VOLT 9.0")
    assert p.parse_error(b'0,"No error"') == (0, "No error")
    assert p.parse_idn(b"a,b,c,d\n").serial == "c"
    for bad in (b"nonsense", b"\xff\xfe", b"1,2"):
        with pytest.raises(p.AwgProtocolError):
            p.parse_error(bad)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.binary(max_size=200))
def test_scpi_parser_raises_only_protocol_errors(data):
    try:
        cmds = p.parse_message(data)
    except p.AwgProtocolError:
        return
    for c in cmds:
        assert c.header


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.binary(max_size=40))
def test_block_and_header_decoders_raise_only_protocol_errors(data):
    for fn in (lambda: p.decode_block(data), lambda: usbtmc.decode_header(data),
               lambda: usbtmc.decode_dev_dep_msg_in(data, 1), lambda: p.parse_idn(data),
               lambda: p.parse_float(data)):
        try:
            fn()
        except ProtocolError as exc:
            assert exc.device == "awg" and exc.command == "decode"


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.binary(max_size=64), st.binary(min_size=0, max_size=50), st.integers(1, 255))
def test_out_stream_parser_resynchronizes_after_garbage(garbage, message, btag):
    frame = usbtmc.encode_dev_dep_msg_out(btag, message)
    stream = garbage + frame
    # garbage that itself holds a plausible header may legitimately swallow bytes; the claim is
    # about streams where the only plausible header is the real one
    starts = [i for i in range(len(stream) - 11) if usbtmc.is_plausible_header(stream, i)]
    parser = usbtmc.UsbtmcOutParser()
    out = []
    for k in range(0, len(stream), 7):  # arbitrary transfer boundaries
        out += parser.feed(stream[k:k + 7])
    assume(starts == [len(garbage)])
    assert len(out) == 1
    assert out[0][0].btag == btag and out[0][1] == message
    assert parser.dropped_bytes == len(garbage)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.lists(st.integers(-32767, 32767), min_size=1, max_size=300))
def test_block_roundtrip_property(codes):
    arr = np.array(codes, dtype=np.int16)
    payload, end = p.decode_block(p.encode_block(p.encode_codes(arr)))
    assert np.array_equal(p.decode_codes(payload), arr)
