"""The simulated digitizer's integer quantizer gives the float quantizer's codes (issue 18)."""

import numpy as np
import pytest

from drivers.digitizer import protocol as p
from sim_devices.digitizer.device import front_end, quantize_codes, quantize_int_codes


@pytest.mark.parametrize("format_bits", [8, 16])
def test_integer_quantizer_matches_round_half_even(format_bits):
    # every code of the container and beyond full scale (the caller clips those), every resolution;
    # the halves (x / step = m + 0.5) go to the even m, as np.round does
    x = np.arange(-(1 << format_bits), 1 << format_bits, dtype=np.int32)
    for res in range(p.MIN_RESOLUTION_BITS, format_bits + 1):
        want, hi_want = quantize_codes(x, res, format_bits)
        got, hi = quantize_int_codes(x, res, format_bits)
        assert hi == hi_want
        np.testing.assert_array_equal(got, want)
    got, _ = quantize_int_codes(np.array([-24, -8, 8, 24, 40]), format_bits - 4, format_bits)
    np.testing.assert_array_equal(got, [-32, 0, 0, 32, 32])   # 16 per step: -1.5 -> -2, 0.5 -> 0, 1.5 -> 2


def test_front_end_keeps_integers_when_the_corner_is_above_nyquist():
    rng = np.random.default_rng(3)
    codes = rng.integers(-33000, 33000, (4, 2, 64)).astype(np.int32)
    cfg = p.Config(sample_rate_hz=5_000_000, record_length=64, segments=4, input_range_mv=1000,
                   channel_mask=0x09, bits=16, resolution_bits=13, bandwidth_hz=500_000_000)
    got, hi = front_end(codes, cfg)
    assert got.dtype.kind == "i"
    want, hi_want = quantize_codes(codes.astype(np.float64), 13, 16)
    assert hi == hi_want
    np.testing.assert_array_equal(got, want)
    # a corner inside the band still filters (float path)
    filt, _ = front_end(codes, p.Config(**{**cfg.__dict__, "bandwidth_hz": 1_000_000}))
    assert filt.dtype == np.float64 and not np.array_equal(filt, want)


def test_int16_quantizer_into_a_record_is_quantize_then_clip():
    # every int16 code, every resolution below 16 bits: the record gets clip(quantize(code)) as the
    # float path gives it (quantize_codes, then the converter's clip to the resolution's top code)
    from drivers.digitizer.protocol import segment_dtype
    from sim_devices.digitizer.device import quantize_int16_into

    codes = np.arange(-32768, 32768, dtype=np.int64).astype(np.int16).reshape(16, 1, 4096)
    recs = np.zeros(16, segment_dtype(1, 4096, 16))
    for res in range(p.MIN_RESOLUTION_BITS, 16):
        quantize_int16_into(recs["data"], codes, res)
        want, hi = quantize_codes(codes.astype(np.float64), res, 16)
        np.testing.assert_array_equal(recs["data"], np.clip(want, -32768, hi).astype(np.int16))
        assert not recs["magic"].any()              # only the samples were written


def test_sim_digitizer_flags_over_range_after_quantizing():
    # a code that rounds above the 14-bit top (32764 -> 32768) is clipped and flagged; one that
    # rounds down to the top is not
    from sim_devices.clock import VirtualClock
    from sim_devices.digitizer.device import CapturedSegments, SimDigitizer

    class Source:
        def capture(self, first, count, cfg):
            codes = np.zeros((count, 1, 8), np.int16)
            codes[0, 0, 3] = 32763                  # rounds to 32764 = top: fine
            codes[1, 0, 5] = 32766                  # rounds to 32768: over range, clipped to 32764
            return CapturedSegments(np.arange(count) * 1e-4, codes, np.zeros((count, 1), bool))

    sim = SimDigitizer(VirtualClock(), Source())
    sim.config = p.Config(sample_rate_hz=5_000_000, record_length=8, segments=2, input_range_mv=1000,
                          channel_mask=0x01, bits=16, resolution_bits=14, bandwidth_hz=500_000_000)
    sim._reset_acquisition()
    sim._armed_cfg, sim._end = sim.config, 2
    sim._make_batch()
    recs = np.frombuffer(sim._batch, dtype=p.segment_dtype(1, 8, 16))
    assert recs["data"][0, 0, 3] == 32764 and recs["data"][1, 0, 5] == 32764
    np.testing.assert_array_equal(recs["overrange"], [0, 1])
