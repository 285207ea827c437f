"""The simulated digitizer's integer quantizer gives the float quantizer's codes (issue 18)."""

import numpy as np
import pytest

from drivers.digitizer import protocol as p
from sim_devices.digitizer import front_end, quantize_codes, quantize_int_codes


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
