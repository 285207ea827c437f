"""The issue-18 fast paths of the detection chain against plain references (same results)."""

import numpy as np
import pytest

from lidard.dsp.detect import cfar
from lidard.dsp.spectrum.rangefft import check_samples
from lidard.dsp.spectrum.window import DspInputError


def _width_by_hand(row, i, max_half):
    # -6 dB full width: on each side the first bin below a quarter of the peak, interpolated linearly
    # with the bin before it; max_half if none within max_half bins (edges clamp to the last bin)
    n, peak = row.size, row[i]
    total = 0.0
    for step in (-1, 1):
        prev, half = peak, float(max_half)
        for s in range(1, max_half + 1):
            v = row[min(max(i + step * s, 0), n - 1)]
            if v < peak / 4:
                half = s - 1 + ((prev - peak / 4) / (prev - v) if prev > v else 0.0)
                break
            prev = v
        total += half
    return total


@pytest.mark.parametrize("in_place", [False, True])
def test_width_6db_is_the_first_crossing_on_each_side(in_place):
    rng = np.random.default_rng(8)
    p = rng.exponential(size=(40, 64))
    p[:, 30:34] = [[20.0, 80.0, 60.0, 10.0]]          # a lobe, and peaks at the edges
    idx = np.stack([np.full(40, 31), rng.integers(0, 64, 40)], axis=1)
    idx[0, 1], idx[1, 1] = 0, 63
    if in_place:
        got = cfar._width_6db(p, None, 9, rows=np.repeat(np.arange(40), 2), cols=idx.ravel()).reshape(40, 2)
    else:
        got = cfar._width_6db(p, idx, 9)
    want = [[_width_by_hand(p[r], idx[r, k], 9) for k in range(2)] for r in range(40)]
    np.testing.assert_array_equal(got, want)


def test_power_checks_name_the_bad_values_without_a_full_map():
    big = np.full((2, 40), 1e307)                       # finite, but its sum overflows
    assert not cfar.cfar_detect_with(big).valid.any()
    for bad, what in ((np.nan, "NaN or infinite"), (np.inf, "NaN or infinite"), (-np.inf, "NaN or infinite"),
                      (-1.0, "negative")):
        p = np.ones((2, 40))
        p[1, 3] = bad
        with pytest.raises(DspInputError, match=what):
            cfar.cfar_detect_with(p)


def test_sample_check_accepts_huge_finite_ramps_and_counts_the_bad_ones():
    assert check_samples(np.full((3, 16), 1e307)).dtype == np.float64
    x = np.ones((3, 16))
    x[1, 4], x[2, 0] = np.nan, np.inf
    with pytest.raises(DspInputError, match=r"1 NaN and 1 infinite sample\(s\); first at index \(1, 4\)"):
        check_samples(x)
