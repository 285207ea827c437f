"""The whole chain (RangeFFT -> CFAR -> sub-bin estimate) on synthetic ramps with known ranges."""

import numpy as np

from lidard.dsp.chain import measure_peaks
from lidard.dsp.spectrum.rangefft import C_M_PER_S, RangeFFT

GAMMA = 1.25e14
FS = 250e6
N = 2048


def ramps(ranges_m, amps, batch=4, iq=False, sigma=1e-3, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    x = np.zeros((batch, N), dtype=complex if iq else float)
    for r, a in zip(ranges_m, amps):
        f = 2 * GAMMA * r / C_M_PER_S
        ph = rng.uniform(0, 2 * np.pi, (batch, 1))
        x += a * (np.exp(1j * (2 * np.pi * f * t + ph)) if iq else np.cos(2 * np.pi * f * t + ph))
    return x + sigma * rng.standard_normal(x.shape)


def test_two_targets_ranges_to_a_millimetre():
    rf = RangeFFT(N, FS, GAMMA, window="hann")
    m = measure_peaks(rf, ramps([23.456, 71.2], [1.0, 0.4]), max_detections=3)
    ok = m.detections.valid
    assert ok[:, :2].all() and not ok[:, 2].any()
    np.testing.assert_allclose(m.range_m[:, 0], 23.456, atol=1e-3)
    np.testing.assert_allclose(m.range_m[:, 1], 71.2, atol=1e-3)
    np.testing.assert_allclose(m.freq_hz[:, 0], 2 * GAMMA * 23.456 / C_M_PER_S, rtol=1e-4)
    assert np.all(m.range_m[:, 2] == 0.0)


def test_range_gate_limits_the_search():
    rf = RangeFFT(N, FS, GAMMA, window="hann", range_gate_m=(40.0, 100.0))
    m = measure_peaks(rf, ramps([23.456, 71.2], [1.0, 0.4]), max_detections=3)
    assert m.detections.valid.sum(axis=1).tolist() == [1, 1, 1, 1]
    np.testing.assert_allclose(m.range_m[:, 0], 71.2, atol=1e-3)


def test_iq_negative_range_and_zero_input():
    rf = RangeFFT(N, FS, GAMMA, window="blackmanharris", iq=True, zero_pad=2)
    m = measure_peaks(rf, ramps([-15.0, 40.0], [1.0, 1.0], iq=True))
    got = np.sort(m.range_m[m.detections.valid].reshape(4, 2), axis=1)
    np.testing.assert_allclose(got, np.tile([-15.0, 40.0], (4, 1)), atol=1e-3)
    z = measure_peaks(rf, np.zeros((2, N), dtype=complex))
    assert not z.detections.valid.any() and np.all(z.range_m == 0.0)
