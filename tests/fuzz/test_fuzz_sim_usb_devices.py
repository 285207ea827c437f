"""Fuzz the request decoders on the device side of the USB seam (sim_devices.awg.device, sim_devices.digitizer.device).

A simulated instrument is a byte-level peer: whatever the host sends, it must answer the way the
real one would (a SCPI error in the error queue, a stalled control pipe) and stay usable, never
crash the bench. AWG: any SCPI text (and any bytes) in well-formed USBTMC DEV_DEP_MSG_OUT
transfers, then ``SYST:ERR?`` still answers. Digitizer: any vendor control request (request code,
wValue, data) either succeeds or raises the pyusb stall error, and ``GET_STATUS`` still decodes.
"""

import errno

import numpy as np
import usb.core
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import usbtmc
from drivers.awg import protocol as awg
from drivers.digitizer import protocol as dig
from sim_devices.awg.device import SimAwg
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.device import CapturedSegments, SimDigitizer

FUZZ = settings(max_examples=200, derandomize=True, deadline=None)

scpi_words = st.sampled_from(["*IDN?", "*RST", "*CLS", "SYST:ERR?", "SOUR:FREQ", "SOUR:VOLT", "SOUR:VOLT:OFFS",
                              "OUTP", "ON", "OFF", "TRIG:SOUR EXT", "DATA:DAC", "#", "#2", "#9", ";", ":", "?", ",",
                              " ", "1e9", "-5", "nan", "inf", "\n", "\"", "'"])
scpi_text = st.lists(st.one_of(scpi_words, st.text(max_size=6)), max_size=8).map("".join)


def _out(btag, message: bytes) -> bytes:
    return usbtmc.encode_dev_dep_msg_out(btag, message, True)


def _query(dev: SimAwg, btag: int, text: bytes) -> bytes:
    dev.handle_bulk_out(awg.AWG_EP_OUT, memoryview(_out(btag, text)))
    req = usbtmc.encode_request_dev_dep_msg_in(usbtmc.next_btag(btag), 4096)
    dev.handle_bulk_out(awg.AWG_EP_OUT, memoryview(req))
    buf = bytearray(8192)
    n = dev.handle_bulk_in(awg.AWG_EP_IN, memoryview(buf))
    msg, _ = usbtmc.decode_dev_dep_msg_in(bytes(buf[:n]), usbtmc.next_btag(btag))
    return msg


@FUZZ
@given(messages=st.lists(st.one_of(scpi_text.map(lambda t: t.encode("utf-8", "replace")), st.binary(max_size=40)),
                         min_size=1, max_size=4))
def test_sim_awg_survives_any_scpi_and_still_answers(messages):
    dev = SimAwg()
    btag = 1
    for m in messages:
        dev.handle_bulk_out(awg.AWG_EP_OUT, memoryview(_out(btag, m)))
        btag = usbtmc.next_btag(btag)
    # an unread answer of a fuzzed query is discarded (-410) by the next command; the error queue
    # still answers in the SCPI format
    code, text = awg.parse_error(_query(dev, btag, b"SYST:ERR?"))
    # SCPI: 0 is "No error", a negative code carries its own non-empty text
    assert (code, text) == (0, "No error") or (code < 0 and text.strip()), (code, text)
    assert awg.parse_idn(_query(dev, usbtmc.next_btag(usbtmc.next_btag(btag)), b"*IDN?")).model


@FUZZ
@given(noise=st.binary(max_size=120))
def test_sim_awg_bulk_out_noise_is_absorbed(noise):
    dev = SimAwg()
    assert dev.handle_bulk_out(awg.AWG_EP_OUT, memoryview(noise)) == len(noise)


class _Source:
    def capture(self, first, count, cfg):
        n_ch = len(cfg.channels)
        return CapturedSegments(codes=np.zeros((count, n_ch, cfg.record_length), dtype=np.int32),
                                overrange=np.zeros((count, n_ch), dtype=bool),
                                trigger_time_s=np.arange(first, first + count, dtype=np.float64) * 1e-4)


@FUZZ
@given(requests=st.lists(st.tuples(st.sampled_from([0x40, 0xC0]),
                                   st.one_of(st.sampled_from([int(r) for r in dig.Req]), st.integers(0, 255)),
                                   st.integers(0, 0xFFFF), st.one_of(st.none(), st.binary(max_size=20))),
                         min_size=1, max_size=6))
def test_sim_digitizer_any_control_request_succeeds_or_stalls(requests):
    dev = SimDigitizer(VirtualClock(), _Source())
    for bm, req, w_value, data in requests:
        try:
            dev.handle_ctrl(bm, req, w_value, 0, data, 64)
        except usb.core.USBError as exc:
            assert exc.errno == errno.EPIPE  # a stall, as a real device refuses a request
            assert dev.last_refused_request == req
    st_ = dig.decode_status(dev.handle_ctrl(0xC0, int(dig.Req.GET_STATUS), 0, 0, None, 64))
    assert st_.state in set(dig.State)
    cfg = dig.decode_config(dev.handle_ctrl(0xC0, int(dig.Req.GET_CONFIG), 0, 0, None, 64))
    dig.validate_mask(cfg.channel_mask)  # whatever was accepted is still a valid configuration
