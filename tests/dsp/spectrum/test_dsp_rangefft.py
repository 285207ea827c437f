"""RangeFFT axes against eq. 2-1/2-3, I/Q sign, averaging, gating and bad input."""

import warnings

import numpy as np
import pytest

from lidard.dsp.spectrum.rangefft import C_M_PER_S, RangeFFT, check_samples
from lidard.dsp.spectrum.window import DspInputError

# Table 2-2: 10 GHz excursion in 80 us -> gamma = 1.25e14 Hz/s; a 50 m target beats at 41.7 MHz.
GAMMA = 10e9 / 80e-6
FS = 250e6
N = 1024


def test_axes_follow_eq_2_1_and_2_3():
    rf = RangeFFT(N, FS, GAMMA, window="rectangular")
    t_ramp = N / FS
    assert rf.delta_f == pytest.approx(1 / t_ramp)
    # eq. 2-3: delta_d = c / (2 gamma T)
    assert rf.delta_r == pytest.approx(C_M_PER_S / (2 * GAMMA * t_ramp))
    assert rf.range_m[10] == pytest.approx(C_M_PER_S * rf.freq_hz[10] / (2 * GAMMA))
    assert rf.freq_hz.size == N // 2 + 1
    padded = RangeFFT(N, FS, GAMMA, zero_pad=4)
    assert padded.delta_r == pytest.approx(rf.delta_r / 4)


def test_target_at_50_m_lands_in_its_range_bin():
    d = 50.0
    f_b = 2 * GAMMA * d / C_M_PER_S
    rf = RangeFFT(N, FS, GAMMA, window="hann")
    t = np.arange(N) / FS
    p = rf.power(np.cos(2 * np.pi * f_b * t))
    assert abs(rf.range_m[np.argmax(p)] - d) <= rf.delta_r / 2


def test_amplitude_scale_real_and_complex():
    t = np.arange(N)
    rf = RangeFFT(N, FS, GAMMA, window="hann")
    spec = rf(3.0 * np.cos(2 * np.pi * 100 * t / N))
    assert np.abs(spec[100]) == pytest.approx(1.5, rel=1e-12)
    iq = RangeFFT(N, FS, GAMMA, window="hann", iq=True)
    spec = iq(2.0 * np.exp(-2j * np.pi * 100 * t / N))
    k = np.argmax(np.abs(spec))
    assert iq.bins[k] == -100 and iq.freq_hz[k] < 0 and iq.range_m[k] < 0
    assert np.abs(spec[k]) == pytest.approx(2.0, rel=1e-12)
    assert iq.index_to_bin(k) == -100 and iq.bin_to_index(-100) == k


def test_complex_input_needs_iq_mode():
    rf = RangeFFT(N, FS, GAMMA)
    with pytest.raises(DspInputError, match="iq=True"):
        rf(np.ones(N, dtype=complex))


def test_incoherent_average_reduces_noise_variance():
    rng = np.random.default_rng(1)
    rf = RangeFFT(N, FS, GAMMA, window="rectangular")
    x = rng.standard_normal((16, N))
    single = rf.power(x[0])
    avg = rf.power(x, average_axis=0)
    assert avg.shape == (N // 2 + 1,)
    # exponential bins: std/mean 1 per chirp, 1/sqrt(16) after averaging 16 chirps
    assert np.std(single[5:-5]) / np.mean(single[5:-5]) == pytest.approx(1.0, abs=0.15)
    assert np.std(avg[5:-5]) / np.mean(avg[5:-5]) == pytest.approx(0.25, abs=0.05)
    with pytest.raises(DspInputError, match="sample axis"):
        rf.power(x, average_axis=-1)


def test_range_gate_keeps_only_the_gated_bins():
    rf = RangeFFT(N, FS, GAMMA, range_gate_m=(10.0, 60.0))
    kept = rf.gate(rf.range_m)
    assert kept.min() >= 10.0 and kept.max() <= 60.0
    assert kept.size == np.count_nonzero((rf.range_m >= 10) & (rf.range_m <= 60))
    with pytest.raises(DspInputError, match="range_gate_m"):
        RangeFFT(N, FS, GAMMA, range_gate_m=(60.0, 10.0))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_or_inf_input_is_a_clear_error(bad):
    x = np.zeros((3, N))
    x[1, 7] = bad
    with pytest.raises(DspInputError, match=r"first at index \(1, 7\)"):
        RangeFFT(N, FS, GAMMA)(x)


def test_wrong_length_and_bad_config_name_the_value():
    with pytest.raises(DspInputError, match="expected 1024"):
        RangeFFT(N, FS, GAMMA)(np.zeros(100))
    with pytest.raises(DspInputError, match="chirp_rate_hz_per_s"):
        RangeFFT(N, FS, -GAMMA)
    with pytest.raises(DspInputError, match="zero_pad"):
        RangeFFT(N, FS, GAMMA, zero_pad=0)
    with pytest.raises(DspInputError, match="dtype"):
        check_samples(np.array(["a"] * 8))


def test_zero_and_constant_input_are_silent_and_finite():
    rf = RangeFFT(N, FS, GAMMA)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for x in (np.zeros((2, N)), np.full((2, N), 0.7)):
            p = rf.power(x)
            assert np.all(np.isfinite(p))
