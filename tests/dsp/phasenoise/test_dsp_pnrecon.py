"""Phase-noise compensation at any range from a quadrature monitor MZI (lidard.dsp.phasenoise.reconstruct; §2.3, issue 15).

Signals built here from the definitions (a Wiener laser phase with Var[phi(t) - phi(t - tau)] = 2 pi
linewidth tau, eq. 2-9; a beat at the TRUE, fractional round trip; the monitor's I = cos and Q = sin of
the same MZI's phase, with white noise and 8-bit quantization), not by the code under test. Fixed seeds.
"""

import math

import numpy as np
import pytest

from lidard.dsp.frame import FrameDsp
from lidard.dsp.phasenoise.compensate import compensated_spectrum
from lidard.dsp.phasenoise.reconstruct import quadrature_delta, reconstruct_phase, whole_delay_samples
from lidard.dsp.spectrum.window import DspInputError

C = 299_792_458.0
FS = 1e9
GAMMA = 8.6e9 / 80e-6
TAU_M = 200e-9
N = 20_000                       # 20 us ramp


def _phase(lw, seed, n, pre):
    t = np.arange(-pre, n) / FS
    ph = np.pi * GAMMA * t ** 2
    if lw > 0:
        ph = ph + np.cumsum(np.random.default_rng(seed).standard_normal(n + pre) * math.sqrt(2 * np.pi * lw / FS))
    return ph


def _record(range_m, tau_c_s, seed, n=N):
    """Beat at the true round trip and the noisy quantized monitor I, Q (monitor noise from seed + 1)."""
    lw = 0.0 if tau_c_s is None else 1.0 / (math.pi * tau_c_s)
    tau = 2 * range_m / C
    pre = int(math.ceil(max(tau, TAU_M) * FS)) + 4
    ph = _phase(lw, seed, n, pre)
    k, grid = np.arange(n) + pre, np.arange(n + pre)
    beat = np.cos(ph[pre:] - np.interp(k - tau * FS, grid, ph) + 0.4)
    th = ph[pre:] - ph[pre - int(TAU_M * FS):pre - int(TAU_M * FS) + n] + 1.1
    rng = np.random.default_rng(seed + 1)
    lsb = 2.0 / 256
    i, q = (np.round((0.3 * f(th) + 2e-3 * rng.standard_normal(n)) / lsb) * lsb for f in (np.cos, np.sin))
    return beat, i, q


def _peak_db(range_m, tau_c_s, seed, quadrature):
    fb = GAMMA * 2 * range_m / C
    peaks = []
    for tc in (None, tau_c_s):
        beat, i, q = _record(range_m, tc, seed)
        cs = compensated_spectrum(beat, i, fs_hz=FS, mzi_delay_s=TAU_M, max_delay_s=1.4e-6,
                                  chirp_rate_hz_per_s=GAMMA, mzi_q=q if quadrature else None)
        j = int(np.argmin(np.abs(cs.freq_hz - fb)))
        peaks.append(cs.comp[j - 3:j + 4].max())
    return 20 * math.log10(peaks[0] / peaks[1])


@pytest.mark.parametrize("range_m", [75.0, 137.3])
def test_off_grid_ranges_recover_within_3_db_at_tau_c_0_1_us(range_m):
    # 75 m is half-way between 2 and 3 x 200 ns: the worst place for the nearest-M compensation
    q = [_peak_db(range_m, 0.1e-6, s, quadrature=True) for s in (11, 12)]
    grid = [_peak_db(range_m, 0.1e-6, s, quadrature=False) for s in (11, 12)]
    assert np.mean(q) <= 3.0
    assert np.mean(q) < np.mean(grid) - 2.0      # the single real MZI does not get there off its grid


def test_zero_linewidth_is_unaffected_by_the_compensation():
    beat, i, q = _record(101.7, None, 5)
    cs = compensated_spectrum(beat, i, fs_hz=FS, mzi_delay_s=TAU_M, max_delay_s=1.4e-6,
                              chirp_rate_hz_per_s=GAMMA, mzi_q=q)
    j = int(np.argmax(cs.raw))
    assert abs(cs.freq_hz[j] - GAMMA * 2 * 101.7 / C) <= 2 * (cs.freq_hz[1] - cs.freq_hz[0])
    assert abs(20 * math.log10(cs.comp[j] / cs.raw[j])) < 0.1


def test_reconstruction_recovers_the_phase_difference_at_a_fractional_delay():
    # exact delta of a Wiener phase: phi(t) - phi(t - tau) for tau = 2.37 tau_m, which no sum of
    # whole delays gives; its variance alone is 2 pi linewidth tau (eq. 2-9)
    lw = 1.0 / (math.pi * 0.1e-6)
    n, d = 8000, 200
    phi = np.cumsum(np.random.default_rng(7).standard_normal(n) * math.sqrt(2 * np.pi * lw / FS))
    delta = np.zeros(n)
    delta[d:] = phi[d:] - phi[:-d]
    delta += 0.3                                   # any constant offset (the MZI's static phase)
    valid = np.zeros(n, dtype=bool)
    valid[400:n - 100] = True
    rec, first = reconstruct_phase(delta, valid, d)
    assert first == 400 - d
    lag = 474
    k = np.arange(1000, n - 100)
    err = (rec[k] - rec[k - lag]) - (phi[k] - phi[k - lag])
    err -= err.mean()
    assert np.var(err) < 0.05 * 2 * np.pi * lw * lag / FS


def test_slips_of_the_unwrapped_monitor_phase_do_not_propagate():
    n, d = 4000, 200
    phi = np.cumsum(np.random.default_rng(2).standard_normal(n) * 0.1)
    delta = np.zeros(n)
    delta[d:] = phi[d:] - phi[:-d]
    valid = np.zeros(n, dtype=bool)
    valid[d:] = True
    slipped = delta.copy()
    slipped[1234:] += 2 * np.pi                    # an unwrap picking the wrong branch
    a, _ = reconstruct_phase(delta, valid, d)
    b, _ = reconstruct_phase(slipped, valid, d)
    np.testing.assert_allclose(np.exp(1j * (b - a)) * np.exp(-1j * (b - a)[d]), 1.0, atol=1e-9)


def test_quadrature_delta_is_the_mzi_phase_minus_the_nominal_fringe():
    # photodiode/ADC offsets on both channels are removed with the ramp mean (the fringe averages out
    # to within a fraction of a cycle: a few hundredths of a radian over 430 fringes)
    k = np.arange(20_000)
    th = 2 * np.pi * GAMMA * TAU_M / FS * k + 0.5 * np.sin(k / 50.0)
    d = quadrature_delta(0.1 + np.cos(th), -0.05 + np.sin(th), fs_hz=FS, beat_hz=GAMMA * TAU_M)
    np.testing.assert_allclose(d - d[0], 0.5 * np.sin(k / 50.0), atol=0.03)


def test_bad_inputs_are_named():
    with pytest.raises(DspInputError, match="mzi_q"):
        quadrature_delta(np.ones(10), np.ones(11), fs_hz=FS, beat_hz=1e6)
    with pytest.raises(DspInputError, match="contiguous"):
        v = np.ones(100, dtype=bool)
        v[50] = False
        reconstruct_phase(np.zeros(100), v, 10)
    # 200 ns at 537.9 MS/s is 107.58 samples: the error names the rate that fits
    with pytest.raises(DspInputError, match="fs_hz = 5.4e"):
        whole_delay_samples(200e-9, 537.9e6)
    assert whole_delay_samples(200e-9, 1e9) == 200


def test_frame_dsp_ranges_an_off_grid_target_with_the_quadrature_monitor():
    # 4 pixels x 2 averages, target at 75 m (off the 200 ns grid), tau_c = 0.1 us
    n_r = 12_000
    dsp = FrameDsp(ramp_samples=n_r, fs_hz=FS, chirp_rate_hz_per_s=GAMMA, wavelength_m=1.55e-6,
                   max_range_m=90.0, min_range_m=1.0, max_speed_mps=0.4, use_fraction=0.7)
    beat, mi, mq = [], [], []
    for s in range(8 * 2):                       # 4 px x 2 avg x (up, down): both ramps give |f_b|
        b, i, q = _record(75.0, 0.1e-6, 100 + s, n=n_r)
        beat.append(b + 0.5 * np.random.default_rng(500 + s).standard_normal(n_r))
        mi.append(i)
        mq.append(q)
    shape = (4, 2, 2 * n_r)
    beat, mi, mq = (np.reshape(np.array(x), shape) for x in (beat, mi, mq))
    res = dsp.process(beat, mzi=mi, mzi_q=mq, mzi_delay_s=TAU_M)
    got = res.range_m[res.present]
    assert res.present.any(axis=1).all()
    assert np.all(np.abs(got - 75.0) < 0.3)
