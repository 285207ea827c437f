"""The health check's measure (lidard.dsp.linearize.chirpcheck): the RMS error of a chirp against the ideal one,
from monitor-MZI records. A chirp whose slope is off by a relative eps has, over the ROI (0.8 of each
ramp, offset free), an RMS error eps x excursion x 0.8 / sqrt(12), and no nonlinearity at all."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidard.dsp.linearize.chirpcheck import ChirpGeometry, chirp_residual

EXCURSION_HZ, RAMP_S, TAU_S = 8.6e9, 80e-6, 200e-9
FS_ADC, FS_DRIVE = 250e6, 100e6


def _records(eps: float, n: int, noise: float = 0.0, bow_hz: float = 0.0, seed: int = 0) -> np.ndarray:
    """Real MZI fringes cos(phi(t) - phi(t - tau)) of a triangle chirp with slope x (1 + eps) and an
    optional parabolic bow (a nonlinearity) of peak ``bow_hz``, one period per record."""
    m = int(round(2 * RAMP_S * FS_ADC))
    t = np.arange(2 * m) / FS_ADC                            # two periods: the delayed copy needs the first
    tp = np.mod(t, 2 * RAMP_S)
    slope = (1 + eps) * EXCURSION_HZ / RAMP_S
    up = tp < RAMP_S
    nu = np.where(up, slope * (tp - RAMP_S / 2), -slope * (tp - 1.5 * RAMP_S))
    x = np.where(up, tp / RAMP_S, (tp - RAMP_S) / RAMP_S) * 2 - 1
    nu = nu + bow_hz * (1 - x * x)
    phi = 2 * np.pi * np.cumsum(nu) / FS_ADC
    k = int(round(TAU_S * FS_ADC))
    fringe = np.cos(phi[m:] - phi[m - k:2 * m - k])
    rng = np.random.default_rng(seed)
    return fringe[None, :] + noise * rng.standard_normal((n, m))


def _drive() -> np.ndarray:
    n = int(round(RAMP_S * FS_DRIVE))
    return np.concatenate([np.linspace(-1, 1, n, endpoint=False), np.linspace(1, -1, n, endpoint=False)])


def _check(y):
    return chirp_residual(y, _drive(), ChirpGeometry(fs_drive_hz=FS_DRIVE, fs_adc_hz=FS_ADC, ramp_s=RAMP_S, excursion_hz=EXCURSION_HZ, mzi_delay_s=TAU_S))


@pytest.mark.parametrize("eps", [2e-4, 1e-3, -5e-4])
def test_a_slope_error_shows_as_error_not_as_nonlinearity(eps):
    r = _check(_records(eps, 4))
    expected = abs(eps) * EXCURSION_HZ * 0.8 / math.sqrt(12)
    assert r.up_error_hz == pytest.approx(expected, rel=0.05)
    assert r.down_error_hz == pytest.approx(expected, rel=0.05)
    assert r.error_hz == pytest.approx(expected, rel=0.05)
    assert r.relative == pytest.approx(r.error_hz / EXCURSION_HZ)
    assert max(r.up_nonlinearity_hz, r.down_nonlinearity_hz) < 0.05 * expected


def test_the_ideal_chirp_checks_clean_and_a_bow_counts_as_nonlinearity():
    clean = _check(_records(0.0, 4))
    assert clean.error_hz < 10e3 and clean.records == 4
    bowed = _check(_records(0.0, 4, bow_hz=1e6))
    # a parabola 1 - x^2 over |x| <= 0.8 with its mean removed: rms 1e6 x 0.8^2 x sqrt(4/45)
    expected = 1e6 * 0.8 ** 2 * math.sqrt(4 / 45)
    assert bowed.up_error_hz == pytest.approx(expected, rel=0.1)
    assert bowed.up_nonlinearity_hz == pytest.approx(expected, rel=0.1)


def test_noise_floor_comes_from_the_records_and_averages_down():
    few, many = _check(_records(0.0, 4, noise=1.0, seed=1)), _check(_records(0.0, 64, noise=1.0, seed=1))
    assert math.isfinite(few.noise_floor_hz) and few.noise_floor_hz > 2 * many.noise_floor_hz
    assert math.isnan(_check(_records(0.0, 1)).noise_floor_hz)


def test_bad_records_are_refused_with_the_expected_shape_named():
    with pytest.raises(ValueError, match=r"records have shape \(2, 100\); expected \(n, 40000\)"):
        _check(np.zeros((2, 100)))
    y = _records(0.0, 2)
    y[0, 5] = np.nan
    with pytest.raises(ValueError, match="monitor records"):
        _check(y)
