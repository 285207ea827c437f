"""The FPSA frame parser keeps its recent decode errors (``FrameParser.errors``, the last 64) for as
long as it lives; a kept error must not keep the frames it was raised through.

In the daemon the driver parses the FPGA's answers on the scan's own thread. A kept error's traceback
held the parser's frame, and Python links a frame object that outlives its call to its caller's frame,
so each garbled answer pinned the whole call stack of the scan that read it with its arrays (measured
in process: 5.3-5.5 MB when the answer came during the linearization health check, 0.2 MB during the
scan) until 64 newer errors pushed it out: the soak's daemon RSS moved in 5.3 MB steps, up and down.
This is not a cycle (the collector cannot free it), so it is checked with plain reference counting.
"""

from __future__ import annotations

import gc
import weakref

import numpy as np

from drivers.errors import ProtocolError
from drivers.fpsa import protocol as p

GARBLED = [b"\x05\x11\x22\x33\x44\x00",        # a COBS frame whose checksum cannot match
           b"\x09\x01\x02\x00"]                # a COBS code running past the frame's end


def _caller_with_array(parser: p.FrameParser, wire: bytes) -> weakref.ref:
    records = np.ones(1 << 16)                 # what a scan's frame holds (its MZI records)
    parser.feed_all(wire)
    return weakref.ref(records)


def test_kept_decode_errors_do_not_hold_the_callers_frames():
    parser = p.FrameParser()
    gc.disable()
    try:
        refs = [_caller_with_array(parser, wire) for wire in GARBLED]
        assert len(parser.errors) == len(GARBLED)
        assert all(isinstance(e, ProtocolError) for e in parser.errors)
        assert [r() is None for r in refs] == [True] * len(GARBLED)
    finally:
        gc.enable()
    # what a driver reads of the error stays: its type, message and device
    assert all(e.device == p.DEVICE and str(e) for e in parser.errors)
