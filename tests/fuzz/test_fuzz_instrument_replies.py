"""Fuzz the reply decoders of the AWG, digitizer and controller codecs not covered in tests/drivers.

Covered elsewhere: SCPI message parsing, IEEE block / USBTMC headers, *IDN?, float replies
(tests/drivers/awg); digitizer segment/status/config decoders and resync (tests/drivers/digitizer);
controller register values, status and identity blocks (tests/drivers/controller). Here: SYST:ERR?
and integer replies, waveform code payloads, the USBTMC OUT stream parser and the digitizer segment
stream parser on pure noise, the controller's flag bits and fault word. Each may return a value or
raise its codec's ProtocolError, nothing else.
"""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import usbtmc
from drivers.awg import protocol as awg
from drivers.controller import protocol as ctl
from drivers.digitizer import protocol as dig
from drivers.errors import ProtocolError

FUZZ = settings(max_examples=300, derandomize=True, deadline=None)


@FUZZ
@given(data=st.binary(max_size=64))
def test_awg_reply_parsers_raise_only_protocol_errors(data):
    for fn in (awg.parse_error, awg.parse_int, awg.decode_codes):
        try:
            fn(data)
        except ProtocolError as exc:
            assert exc.device == "awg" and exc.command == "decode"


@FUZZ
@given(code=st.integers(-999, 999), text=st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126),
                                                  max_size=40))
def test_awg_error_reply_roundtrip(code, text):
    assert awg.parse_error(awg.format_error(code, text)) == (code, text)


@FUZZ
@given(chunks=st.lists(st.binary(max_size=80), max_size=8))
def test_usbtmc_out_parser_on_noise_yields_only_plausible_messages(chunks):
    parser = usbtmc.UsbtmcOutParser()
    got = []
    for ch in chunks:
        got += parser.feed(ch)
    for header, message in got:
        assert isinstance(message, bytes)
        assert usbtmc.is_plausible_header(usbtmc.encode_dev_dep_msg_out(header.btag, message, header.eom))
    assert parser.dropped_bytes <= sum(map(len, chunks))


@FUZZ
@given(chunks=st.lists(st.binary(max_size=120), max_size=8), with_magic=st.booleans())
def test_digitizer_stream_parser_on_noise_never_raises(chunks, with_magic):
    parser = dig.SegmentStreamParser(max_payload=4096)
    total = 0
    for ch in chunks:
        if with_magic:
            ch = dig.MAGIC + ch  # headers that start right but are garbage after the magic
        total += len(ch)
        for header, samples in parser.feed(ch):
            assert samples.shape == (header.n_channels, header.n_samples)
    assert parser.dropped_bytes <= total


@FUZZ
@given(index=st.integers(0, 2**32 - 1), t_ns=st.integers(0, 2**64 - 1), bits=st.sampled_from([8, 16]),
       mask=st.sampled_from([0x01, 0x06, 0x09, 0x0E]), n=st.integers(1, 16), noise=st.binary(max_size=50),
       seed=st.integers(0, 99))
def test_digitizer_stream_parser_finds_a_good_segment_after_noise(index, t_ns, bits, mask, n, noise, seed):
    dig.validate_mask(mask)
    rng = np.random.default_rng(seed)
    n_ch = bin(mask).count("1")
    dt = dig.sample_dtype(bits)
    info = np.iinfo(dt)
    samples = rng.integers(info.min, info.max, size=(n_ch, n), endpoint=True).astype(dt)
    seg = dig.encode_segment(index, t_ns, mask, bits, 0, samples)
    parser = dig.SegmentStreamParser()
    got = parser.feed(noise.replace(dig.MAGIC, b"") + seg)
    assert len(got) == 1 and got[0][0].index == index and np.array_equal(got[0][1], samples)


@FUZZ
@given(bits=st.lists(st.one_of(st.booleans(), st.integers(0, 1)), max_size=12))
def test_controller_flags_decode(bits):
    try:
        f = ctl.decode_flags(bits)
    except ProtocolError as exc:
        assert exc.device == "controller" and len(bits) < ctl.FLAGS_BLOCK[1]
        return
    assert f.interlock_closed == bool(bits[ctl.INTERLOCK_CLOSED.address])
    assert f.hv_on == bool(bits[ctl.HV_ON.address])


@FUZZ
@given(word=st.one_of(st.integers(-5, 0x1FFFF), st.booleans(), st.floats(allow_nan=True), st.none()))
def test_controller_fault_word_decodes_or_protocol_error(word):
    try:
        faults = ctl.decode_faults(word)
    except ProtocolError as exc:
        assert exc.device == "controller"
        # an undefined bit or a non-word is never read as "no fault"
        return
    assert ctl.encode_faults(faults) == word
