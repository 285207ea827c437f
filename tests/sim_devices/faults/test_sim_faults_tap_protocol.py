"""The digitizer's `tap` channel on the wire: golden vectors D6/D7 of docs/protocols/digitizer.md,
mask rules (bit 4 added, earlier masks unchanged) and the overrange flag of a tap+beat segment."""

import numpy as np
import pytest

from drivers.digitizer import protocol as p

# docs/protocols/digitizer.md, hand-assembled
D6 = bytes.fromhex("44 47 53 47 01 10 10 00 02 00 00 00 02 00 00 00"
                   "80 84 1E 00 00 00 00 00 7D 4D 94 C9 07 AE D8 9E"
                   "52 18 52 18")
D7 = bytes.fromhex("44 47 53 47 01 08 11 01 07 00 00 00 01 00 00 00"
                   "00 00 00 00 00 00 00 00 90 EF 12 FA 48 3E DB A7"
                   "7F 18")


def test_d6_tap_segment_decodes_and_encodes():
    h, samples, used = p.decode_segment(D6)
    assert used == len(D6)
    assert (h.index, h.channel_mask, h.bits, h.overrange, h.trigger_time_ns) == (2, 0x10, 16, 0, 2_000_000)
    assert samples.tolist() == [[6226, 6226]]
    # 6226 LSB of a 1 V range at 16 bit is the 95 mV of one open beam
    assert samples[0, 0] * 1.0 / 2**16 == pytest.approx(0.095, abs=1e-5)
    assert p.encode_segment(2, 2_000_000, p.channel_mask(("tap",)), 16, 0, np.array([[6226, 6226]])) == D6


def test_d7_beat_and_tap_with_the_beat_overrange():
    h, samples, _ = p.decode_segment(D7)
    assert p.channels_of(h.channel_mask) == ("beat", "tap")
    assert h.overrange == 0b01 and samples.tolist() == [[127], [24]]
    assert p.encode_segment(7, 0, 0x11, 8, 0b01, np.array([[127], [24]])) == D7
    parsed = p.SegmentStreamParser().feed(b"\xff" * 5 + D7 + D6)
    assert [hh.index for hh, _ in parsed] == [7, 2]


def test_mask_rules_with_tap():
    assert p.channel_mask(("beat", "tap")) == 0x11
    assert p.channel_mask(("beat_i", "beat_q", "mzi", "tap")) == 0x1E
    assert p.channels_of(0x10) == ("tap",)
    for bad in (0x20, 0x31, 0x80):
        with pytest.raises(p.DigitizerProtocolError):
            p.validate_mask(bad)
    # masks valid before the tap channel keep their meaning
    assert p.channels_of(0x09) == ("beat", "mzi")
    assert p.channels_of(0x0E) == ("beat_i", "beat_q", "mzi")
