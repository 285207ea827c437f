"""The records' white noise (sim_devices.world.gauss): standard normal, independent, reproducible."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_devices.world.gauss import standard_normal_f32


def _normal_cdf(x):
    return 0.5 * (1.0 + np.vectorize(math.erf)(x / math.sqrt(2.0)))


def test_moments_and_distribution_of_a_standard_normal():
    z = standard_normal_f32(np.random.default_rng(7), (400, 1001)).astype(np.float64)
    n = z.size
    assert z.dtype == np.float64 and abs(z.mean()) < 5 / math.sqrt(n)
    assert abs(z.var() - 1.0) < 5 * math.sqrt(2.0 / n)
    assert abs(np.mean(z ** 4) - 3.0) < 5 * math.sqrt(96.0 / n)       # kurtosis of a Gaussian
    # Kolmogorov-Smirnov distance on a subsample (critical value 1.63 / sqrt(m) at 1 %)
    s = np.sort(z.ravel()[::40])
    m = s.size
    ks = np.max(np.abs(_normal_cdf(s) - np.arange(1, m + 1) / m))
    assert ks < 1.63 / math.sqrt(m)
    # the tails are not cut: the 4-sigma rate (6.3e-5) within its Poisson noise
    assert abs(np.mean(np.abs(z) > 4.0) - 6.334e-5) < 5 * math.sqrt(6.334e-5 / n)


def test_the_two_halves_of_each_pair_are_uncorrelated_and_white():
    z = standard_normal_f32(np.random.default_rng(8), (2, 200_000)).astype(np.float64)
    a, b = z[0], z[1]                             # cos half and sin half of the same pairs
    tol = 5 / math.sqrt(a.size)
    assert abs(np.mean(a * b)) < tol              # uncorrelated
    assert abs(np.mean(a * a * b * b) - 1.0) < 5 * math.sqrt(8.0 / a.size)   # independent radii would give 1
    assert abs(np.mean(a[1:] * a[:-1])) < tol     # white along a record


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
