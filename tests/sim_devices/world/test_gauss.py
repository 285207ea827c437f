"""The records' white noise (sim_devices.world.gauss): standard normal, independent across samples,
records and channels, a function of (stream key, record, channel, sample) only, and its polynomial
log and sine accurate to far below a float32 sample's rounding."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_devices.world import gauss
from sim_devices.world.gauss import NoiseStream, normal_rows, record_keys, standard_normal_f32, stream_key


def _normal_cdf(x):
    return 0.5 * (1.0 + np.vectorize(math.erf)(x / math.sqrt(2.0)))


def _rows(rows, n, *, key=7, first=0, channel="beat"):
    return normal_rows(record_keys(NoiseStream(stream_key(key), first), 0, rows, channel), n).astype(np.float64)


def test_moments_and_distribution_of_a_standard_normal():
    z = _rows(400, 1001)
    n = z.size
    assert abs(z.mean()) < 5 / math.sqrt(n)
    assert abs(z.var() - 1.0) < 5 * math.sqrt(2.0 / n)
    assert abs(np.mean(z ** 3)) < 5 * math.sqrt(15.0 / n)              # skewness 0
    assert abs(np.mean(z ** 4) - 3.0) < 5 * math.sqrt(96.0 / n)       # kurtosis of a Gaussian
    # Kolmogorov-Smirnov distance on a subsample (critical value 1.63 / sqrt(m) at 1 %)
    s = np.sort(z.ravel()[::40])
    m = s.size
    ks = np.max(np.abs(_normal_cdf(s) - np.arange(1, m + 1) / m))
    assert ks < 1.63 / math.sqrt(m)


@pytest.mark.parametrize("k_sigma", [2.0, 3.0, 4.0])
def test_tail_fractions_within_their_poisson_noise(k_sigma):
    z = _rows(400, 10_000, key=3)
    p = math.erfc(k_sigma / math.sqrt(2.0))                         # P(|z| > k)
    assert abs(np.mean(np.abs(z) > k_sigma) - p) < 5 * math.sqrt(p / z.size)


def test_the_radius_reaches_past_8_sigma_and_the_log_is_float64_accurate():
    # every 53-bit uniform U = (w >> 11 + 1) / 2**53, from the smallest (w = 0) to 1, and random words
    rng = np.random.default_rng(0)
    w = np.concatenate([np.array([0, 1 << 11, 2 << 11, (1 << 64) - 1], dtype=np.uint64),
                        rng.integers(0, 1 << 64, 100_000, dtype=np.uint64, endpoint=False),
                        (rng.integers(0, 1 << 20, 1000, dtype=np.uint64) << np.uint64(11)),       # tiny U
                        np.uint64((1 << 64) - 1) - (rng.integers(0, 1 << 30, 1000, dtype=np.uint64) << np.uint64(11))])
    u = ((w >> np.uint64(11)).astype(np.float64) + 1.0) * 2.0 ** -53
    want = np.sqrt(-2.0 * np.log(u))
    got = gauss._radius(w[None, :], np.ones(1))[0]
    assert got[0] == pytest.approx(math.sqrt(2.0 * 53 * math.log(2.0)), rel=1e-14) and got[0] > 8.5
    assert got[3] == 0.0                                            # U = 1
    ok = want > 1e-6                   # near U = 1 the radius is sqrt of a tiny number: relative of that
    assert np.max(np.abs(got[ok] / want[ok] - 1.0)) < 1e-13
    assert np.max(np.abs(got - want)) < 1e-12


def test_the_angle_polynomials_against_libm():
    a = np.arange(0, 1 << gauss.ANGLE_BITS, 997, dtype=np.uint64)
    w = np.concatenate([a, [(1 << gauss.ANGLE_BITS) - 1]]).astype(np.uint64) << np.uint64(64 - gauss.ANGLE_BITS)
    theta = ((w >> np.uint64(64 - gauss.ANGLE_BITS)).astype(np.float64) + 0.5) * gauss.ANGLE_STEP
    c, s = gauss._cos_sin(w[None, :])
    assert np.max(np.abs(c[0] - np.cos(theta))) < 1e-11
    assert np.max(np.abs(s[0] - np.sin(theta))) < 1e-11


def test_white_along_a_record_and_the_pair_halves_independent():
    z = _rows(200, 4000, key=8)
    n = z.size
    tol = 5 / math.sqrt(n)
    for lag in (1, 2, 3, 7, 2000):                 # 2000: the cosine and sine of the same pairs
        assert abs(np.mean(z[:, lag:] * z[:, :-lag])) < 5 / math.sqrt(z[:, lag:].size), lag
    a, b = z[:, :2000], z[:, 2000:]
    assert abs(np.mean(a * b)) < tol * math.sqrt(2)
    assert abs(np.mean(a * a * b * b) - 1.0) < 5 * math.sqrt(8.0 / a.size)   # independent halves: E = 1


def test_independent_across_records_channels_and_streams():
    n = 2000
    beat = _rows(300, n, key=9)
    tol = 5 / math.sqrt(299 * n)
    assert abs(np.mean(beat[1:] * beat[:-1])) < tol                   # neighbouring records
    for other in (_rows(300, n, key=9, channel="beat_q"), _rows(300, n, key=9, channel="mzi"),
                  _rows(300, n, key=10), _rows(300, n, key=9, first=1)[:-1]):
        m = min(len(other), len(beat))
        assert abs(np.mean(beat[:m] * other[:m])) < 5 / math.sqrt(m * n)
    # the same record seen from a stream starting one record later: the same noise, not a correlate
    assert np.array_equal(_rows(300, n, key=9, first=1)[:-1], beat[1:])


def test_a_record_is_a_function_of_key_record_and_channel_only():
    st = NoiseStream(stream_key(1, 2, 3), 100)
    whole = normal_rows(record_keys(st, 0, 12, "mzi_q"), 501, 2.0)
    # any cut, in any order, from a stream shifted to any first record: the same rows
    for start, count in ((0, 5), (5, 7), (11, 1)):
        assert np.array_equal(normal_rows(record_keys(st.shifted(start), 0, count, "mzi_q"), 501, 2.0),
                              whole[start:start + count])
        assert np.array_equal(normal_rows(record_keys(st, start, count, "mzi_q"), 501, 2.0), whole[start:start + count])
    assert stream_key(1, 2, 3) != stream_key(1, 2, 4) != stream_key(2, 1, 3)
    with pytest.raises(ValueError, match="key must be a 64-bit word"):
        NoiseStream(-1)
    with pytest.raises(ValueError, match="first >= 0"):
        NoiseStream(5, -2)


@pytest.mark.parametrize("shape", [(3, 5), (7,), (1, 1), (0, 4)])
def test_shape_dtype_and_reproducibility(shape):
    z1 = standard_normal_f32(np.random.default_rng(1), shape)
    z2 = standard_normal_f32(np.random.default_rng(1), shape)
    assert z1.shape == shape and z1.dtype == np.float32
    assert np.array_equal(z1, z2) and np.all(np.isfinite(z1))


def test_scale_is_the_standard_deviation():
    z = standard_normal_f32(np.random.default_rng(4), (100, 1000), 3e-4).astype(np.float64)
    assert abs(z.std() / 3e-4 - 1.0) < 5 * math.sqrt(0.5 / z.size)
    unit = standard_normal_f32(np.random.default_rng(4), (100, 1000))
    assert np.allclose(z, unit * 3e-4, rtol=1e-6, atol=0)     # the same draws, scaled
    keys = record_keys(NoiseStream(5), 0, 3, "beat")
    per_row = normal_rows(keys, 64, np.array([1.0, 0.0, 2.0]))
    assert np.all(per_row[1] == 0) and np.allclose(per_row[2], 2 * normal_rows(keys, 64)[2], rtol=1e-6)
