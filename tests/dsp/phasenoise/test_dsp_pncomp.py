"""Phase-noise compensation from the monitor MZI (§2.3): peak recovery at tau = M tau_m, detection.

Signals are built here with plain numpy: one Wiener phase realization shared by the LiDAR beat and
the monitor MZI, a linear chirp, integer-sample delays.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidard.dsp.phasenoise.compensate import compensated_spectrum, mzi_phase_noise

FS = 1e9
RAMP_S = 20e-6
GAMMA = 8.6e9 / 80e-6          # Hz/s, the default chirp rate
TAU_M = 200e-9                 # the shipped monitor delay (config [monitor] delay_s; beat 21.5 MHz)
C = 299_792_458.0


def ramp(tau_s, linewidth_hz, seed, *, tau_m=TAU_M, noise_v=0.0):
    rng = np.random.default_rng(seed)
    n = int(RAMP_S * FS)
    d, dm = int(round(tau_s * FS)), int(round(tau_m * FS))
    pre = d + dm + 10
    t = np.arange(-pre, n) / FS
    phase = np.pi * GAMMA * t ** 2
    if linewidth_hz > 0:
        phase = phase + np.cumsum(rng.standard_normal(n + pre) * math.sqrt(2 * np.pi * linewidth_hz / FS))
    beat = np.cos(phase[pre:] - phase[pre - d:pre - d + n] + 0.3)
    if noise_v:
        beat = beat + noise_v * rng.standard_normal(n)
    mzi = 0.3 * np.cos(phase[pre:] - phase[pre - dm:pre - dm + n] + 1.1)
    return beat, mzi


def peak(cs, f_hz, which):
    i = int(np.argmin(np.abs(cs.freq_hz - f_hz)))
    return getattr(cs, which)[i - 3:i + 4].max()


def spectrum(beat, mzi, tau_m=TAU_M, **kw):
    kw.setdefault("chirp_rate_hz_per_s", GAMMA)
    return compensated_spectrum(beat, mzi, fs_hz=FS, mzi_delay_s=tau_m, max_delay_s=1.2e-6, **kw)


def test_zero_linewidth_is_left_alone_and_mzi_frequency_is_measured():
    beat, mzi = ramp(1e-6, 0.0, 1)
    cs = spectrum(beat, mzi)
    assert cs.f_mzi_hz == pytest.approx(GAMMA * TAU_M, rel=1e-4)
    fb = GAMMA * 1e-6
    assert abs(cs.peak_gain_db(fb)) < 0.1
    pn = mzi_phase_noise(mzi, fs_hz=FS, edge_s=1e-6)          # beat frequency measured, not given
    assert pn.f_mzi_hz == pytest.approx(GAMMA * TAU_M, rel=1e-4)
    assert np.abs(pn.delta_rad[pn.valid]).max() < 0.05
    assert abs(spectrum(beat, mzi, chirp_rate_hz_per_s=None).peak_gain_db(fb)) < 0.1


def test_peak_recovered_within_3db_at_m_tau_m():
    tau = 1.0e-6                              # 150 m
    tau_c = tau / 6
    lw = 1.0 / (math.pi * tau_c)
    fb = GAMMA * tau
    on_bin = 0
    for seed in (1, 2, 3, 4):
        ref = peak(spectrum(*ramp(tau, 0.0, seed)), fb, "raw")
        noisy = spectrum(*ramp(tau, lw, seed))
        # the coherent peak collapses without compensation (e^{-tau/tau_c} expected in amplitude)
        assert peak(noisy, fb, "raw") < ref * 10 ** (-12 / 20)
        i = int(np.argmin(np.abs(noisy.freq_hz - fb)))
        # height within 3 dB of the zero-linewidth laser, searched over +-8 bins ...
        assert noisy.comp[i - 8:i + 9].max() > ref * 10 ** (-3 / 20)
        # ... and at the right bin (the known chirp rate fixes the deterministic line)
        on_bin += int(abs(int(np.argmax(noisy.comp[i - 8:i + 9])) - 8) <= 1)
    assert on_bin == 4


def test_off_grid_target_still_gains():
    tau = 1.04e-6                             # 0.2 tau_m away from M tau_m
    lw = 1.0 / (math.pi * 1e-6 / 6)
    cs = spectrum(*ramp(tau, lw, 7))
    assert cs.peak_gain_db(GAMMA * tau) > 6.0
    assert cs.m_of_bin[np.argmin(np.abs(cs.freq_hz - GAMMA * tau))] == round(tau / TAU_M)


def test_target_missed_before_is_detected_after():
    tau = 1.0e-6
    lw = 1.0 / (math.pi * tau / 6)
    beat, mzi = ramp(tau, lw, 4, noise_v=2.0)
    cs = spectrum(beat, mzi)
    fb = GAMMA * tau

    def detected(spec):
        i = int(np.argmin(np.abs(cs.freq_hz - fb)))
        ref = np.concatenate([spec[i - 300:i - 30], spec[i + 30:i + 300]])
        # CFAR-like: cell-averaged power of the reference cells times a factor for Pfa ~ 1e-6
        thr = np.mean(ref ** 2) * math.log(1e6)
        return spec[i - 3:i + 4].max() ** 2 > thr
    assert not detected(cs.raw)
    assert detected(cs.comp)


def test_short_monitor_mzi_gains_less_than_long_one():
    """The Hilbert phase of a real beat keeps only |f - f_mzi| < f_mzi of the noise: a 10 ns MZI (1 MHz
    beat) recovers less than a 100 ns one; both still help."""
    tau = 1.0e-6
    lw = 1.0 / (math.pi * tau / 6)
    fb = GAMMA * tau
    g_short = spectrum(*ramp(tau, lw, 5, tau_m=10e-9), tau_m=10e-9).peak_gain_db(fb)
    g_long = spectrum(*ramp(tau, lw, 5, tau_m=100e-9), tau_m=100e-9).peak_gain_db(fb)
    assert g_long > 0.0
    assert g_short > 0.0
    assert g_long > g_short + 6.0


def test_bad_input():
    beat, mzi = ramp(1e-6, 0.0, 1)
    bad = beat.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="beat"):
        spectrum(bad, mzi)
    bad = mzi.copy()
    bad[3] = np.inf
    with pytest.raises(ValueError, match="mzi"):
        spectrum(beat, bad)
    with pytest.raises(ValueError, match="same length"):
        spectrum(beat, mzi[:-1])
    with pytest.raises(ValueError, match="mzi_delay_s"):
        compensated_spectrum(beat, mzi, fs_hz=FS, mzi_delay_s=0.0, max_delay_s=1e-6)


@pytest.mark.parametrize("tau_c", [0.64e-6, 0.1e-6])
@pytest.mark.parametrize("range_m", [30.0, 75.0, 150.0])
def test_within_3db_of_zero_linewidth_with_the_shipped_delay(tau_c, range_m):
    """Issue 3 target, for both preset coherence times, at the nearest M tau_m to each range."""
    from lidard.config import Monitor
    assert Monitor().delay_s == TAU_M                  # the tests use what ships
    tau = max(1, round(2 * range_m / C / TAU_M)) * TAU_M
    fb = GAMMA * tau
    lw = 1.0 / (math.pi * tau_c)
    for seed in (11, 12):
        ref = peak(spectrum(*ramp(tau, 0.0, seed)), fb, "raw")
        noisy = spectrum(*ramp(tau, lw, seed))
        assert peak(noisy, fb, "comp") > ref * 10 ** (-3 / 20)
        if tau / tau_c >= 6:
            # the coherent peak collapsed without compensation: e^{-tau/tau_c} < -26 dB expected
            assert peak(noisy, fb, "raw") < ref * 10 ** (-10 / 20)


def test_broad_linewidth_target_missed_raw_is_detected_compensated():
    """tau_c = 0.1 us, 75 m (tau / tau_c = 5): white noise that hides the raw peak, not the compensated one."""
    tau = round(2 * 75.0 / C / TAU_M) * TAU_M
    fb = GAMMA * tau
    beat, mzi = ramp(tau, 1.0 / (math.pi * 0.1e-6), 6, noise_v=2.0)
    cs = spectrum(beat, mzi)
    i = int(np.argmin(np.abs(cs.freq_hz - fb)))

    def detected(spec):
        ref = np.concatenate([spec[i - 300:i - 30], spec[i + 30:i + 300]])
        return spec[i - 3:i + 4].max() ** 2 > np.mean(ref ** 2) * math.log(1e6)
    assert not detected(cs.raw)
    assert detected(cs.comp)
