"""Rife-Boorstyn CRLB: conventions cross-checked against each other and a Monte-Carlo ML fit."""

import numpy as np
import pytest

from lidard.dsp.ranging.crlb import crlb_freq_var, crlb_freq_var_post_fft, post_fft_snr
from lidard.dsp.spectrum.window import DspInputError


def test_complex_bound_closed_form():
    # var(omega) >= 6 / (SNR N (N^2 - 1)) rad^2; bins = omega N / (2 pi)
    n, snr = 256, 0.5
    var_omega = 6 / (snr * n * (n**2 - 1))
    assert crlb_freq_var(snr, n) == pytest.approx(var_omega * (n / (2 * np.pi)) ** 2)
    assert crlb_freq_var(snr, n, fs_hz=1e6) == pytest.approx(var_omega * (1e6 / (2 * np.pi)) ** 2)


def test_post_fft_form_is_the_same_bound_for_real_and_complex():
    n = 512
    for real in (False, True):
        snr = 0.3
        rho = post_fft_snr(snr, n, real=real)
        assert crlb_freq_var(snr, n, real=real) == pytest.approx(crlb_freq_var_post_fft(rho, n))
    assert crlb_freq_var_post_fft(100.0, n) == pytest.approx(3 / (2 * np.pi**2 * 100), rel=1e-5)


def test_post_fft_snr_matches_a_measured_spectrum():
    rng = np.random.default_rng(0)
    n, amp, sigma = 256, 1.0, 2.0
    x = amp * np.cos(2 * np.pi * 32 * np.arange(n) / n) + sigma * rng.standard_normal((4000, n))
    spec = np.abs(np.fft.rfft(x, axis=-1)) ** 2
    measured = (amp * n / 2) ** 2 / np.mean(spec[:, 40:120])
    assert measured == pytest.approx(post_fft_snr(amp**2 / 2 / sigma**2, n, real=True), rel=0.03)


def test_bad_snr_is_named():
    with pytest.raises(DspInputError, match="snr_linear"):
        crlb_freq_var(0.0, 64)
    with pytest.raises(DspInputError, match="n="):
        crlb_freq_var_post_fft(10.0, 1)
