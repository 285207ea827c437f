"""Sub-bin estimators checked against the analytic frequency of seeded synthetic tones."""

import warnings

import numpy as np
import pytest

from lidard.dsp.ranging.crlb import crlb_freq_var_post_fft
from lidard.dsp.ranging.estimators import DEFAULT_METHOD, ESTIMATOR_NAMES, ESTIMATORS, estimate
from lidard.dsp.spectrum.rangefft import RangeFFT
from lidard.dsp.spectrum.window import DspInputError

N = 512


def tones(freq_bins, n=N, batch=1, post_fft_snr_db=None, seed=0, iq=False, amp=1.0):
    """Real cosines (or complex exponentials) at freq_bins with random phase; white noise set so
    that the post-FFT SNR (rectangular window, on-bin peak power / noise power per bin) is as given."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    f = np.broadcast_to(np.asarray(freq_bins, dtype=float), (batch,))[:, None]
    ph = rng.uniform(0, 2 * np.pi, (batch, 1))
    x = amp * (np.exp(1j * (2 * np.pi * f * t / n + ph)) if iq else np.cos(2 * np.pi * f * t / n + ph))
    if post_fft_snr_db is not None:
        rho = 10 ** (post_fft_snr_db / 10)
        if iq:
            sigma = np.sqrt(amp**2 * n / rho)
            x = x + sigma / np.sqrt(2) * (rng.standard_normal(x.shape) + 1j * rng.standard_normal(x.shape))
        else:
            sigma = np.sqrt(amp**2 * n / (4 * rho))
            x = x + sigma * rng.standard_normal(x.shape)
    return x


def test_registry_is_one_dict_keyed_by_the_literal():
    assert tuple(ESTIMATORS) == ESTIMATOR_NAMES
    assert DEFAULT_METHOD in ESTIMATORS
    with pytest.raises(DspInputError, match="choose one of"):
        estimate(tones(10.0), np.array([10]), method="candan")


@pytest.mark.parametrize("method", ["jacobsen", "quinn2", "aboutanios", "newton"])
@pytest.mark.parametrize("window", ["rectangular", "hann", "blackmanharris"])
def test_noise_free_offsets_are_recovered(method, window):
    offsets = np.linspace(-0.5, 0.5, 11)
    f = 123.0 + offsets
    x = np.stack([tones(fi)[0] for fi in f])
    rf = RangeFFT(N, 1.0, 1.0, window=window)
    k = np.argmax(rf.power(x), axis=-1)
    est = estimate(x, k, method=method, window=window)
    tol = {"jacobsen": 2e-4, "quinn2": 2e-3, "aboutanios": 2e-3, "newton": 1e-6}[method]
    np.testing.assert_allclose(est, f, atol=tol)


def test_parabolic_is_biased_but_within_a_tenth_of_a_bin_and_argmax_is_the_bin():
    f = 77.0 + np.linspace(-0.5, 0.5, 11)
    x = np.stack([tones(fi)[0] for fi in f])
    k = np.rint(f).astype(int)
    par = estimate(x, k, method="parabolic", window="hann")
    assert np.max(np.abs(par - f)) < 0.1
    assert np.max(np.abs(par - f)) > 1e-3  # the known bias of the log-parabola on a Hann lobe
    np.testing.assert_array_equal(estimate(x, k, method="argmax"), k.astype(float))


@pytest.mark.parametrize("zero_pad", [2, 4])
def test_zero_padded_grid_units(zero_pad):
    f = 60.3
    x = tones(f, batch=1)
    rf = RangeFFT(N, 1.0, 1.0, window="hann", zero_pad=zero_pad)
    k = np.argmax(rf.power(x), axis=-1)
    for method in ("jacobsen", "newton", "aboutanios"):
        est = estimate(x, k, method=method, window="hann", zero_pad=zero_pad, spectrum=rf(x))
        assert est[0] / zero_pad == pytest.approx(f, abs=2e-3), method


def test_complex_iq_negative_frequency():
    f = -40.27
    x = tones(f, iq=True)
    rf = RangeFFT(N, 1.0, 1.0, window="hann", iq=True)
    k = rf.index_to_bin(np.argmax(rf.power(x), axis=-1))
    assert k[0] == -40
    for method in ("jacobsen", "quinn2", "aboutanios", "newton"):
        assert estimate(x, k, method=method)[0] == pytest.approx(f, abs=2e-3), method


def test_several_peaks_per_ramp_and_leading_dims():
    x = tones(50.2, batch=6) + tones(150.7, batch=6, seed=3)
    x = x.reshape(2, 3, N)
    k = np.broadcast_to(np.array([50, 151]), (2, 3, 2))
    est = estimate(x, k, method="newton")
    assert est.shape == (2, 3, 2) and est.dtype == np.float64
    np.testing.assert_allclose(est[..., 0], 50.2, atol=2e-3)
    np.testing.assert_allclose(est[..., 1], 150.7, atol=2e-3)


def test_near_dc_and_near_nyquist():
    # Real tones 2.3 bins from DC and from Nyquist: the default models the image, so it stays
    # accurate where image-blind estimators are biased by ~1/(2 pi^2 k).
    for f in (2.3, N / 2 - 2.3):
        x = tones(f, batch=8, post_fft_snr_db=40, seed=5)
        k = np.full(8, int(np.rint(f)))
        err = estimate(x, k) - f
        assert np.sqrt(np.mean(err**2)) < 0.02, f


def test_all_zero_and_constant_input_give_finite_results_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for x in (np.zeros((3, N)), np.full((3, N), 2.5)):
            for method in ESTIMATOR_NAMES:
                est = estimate(x, np.array([0, 5, 100]), method=method)
                assert np.all(np.isfinite(est)), method


def test_bad_inputs_are_named():
    x = tones(10.0, batch=2)
    with pytest.raises(DspInputError, match="NaN"):
        estimate(np.where(np.arange(N) == 3, np.nan, x), np.array([10, 10]))
    with pytest.raises(DspInputError, match="peak_bins shape"):
        estimate(x, np.array([10, 10, 10]))
    with pytest.raises(DspInputError, match="integers"):
        estimate(x, np.array([10.5, 10.0]))
    with pytest.raises(DspInputError, match="spectrum shape"):
        estimate(x, np.array([10, 10]), spectrum=np.zeros((2, 10)))


def test_snr_sweep_threshold_behaviour_without_nan():
    """Post-FFT SNR 5..40 dB: outliers (a noise peak beating the tone in a 256-bin search) fall
    with SNR and vanish past threshold, where the error follows the CRLB; never NaN or warnings."""
    rf = RangeFFT(N, 1.0, 1.0, window="hann")
    rates = []
    for snr_db in range(5, 41, 5):
        x = tones(100.37, batch=400, post_fft_snr_db=snr_db, seed=snr_db)
        k = np.argmax(rf.power(x)[:, 1:], axis=-1) + 1
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            est = estimate(x, k, spectrum=rf(x))
        assert np.all(np.isfinite(est))
        err = np.abs(est - 100.37)
        rates.append(np.mean(err > 0.5))
        if snr_db >= 20:
            assert rates[-1] == 0.0
            assert np.sqrt(np.mean(err**2)) < 1.5 * np.sqrt(crlb_freq_var_post_fft(10 ** (snr_db / 10), N))
    assert rates[0] > 0.5  # 5 dB is below threshold
    assert all(b <= a + 0.02 for a, b in zip(rates, rates[1:]))


@pytest.mark.parametrize("offset", [0.0, 0.2, 0.35, 0.5])
def test_default_rmse_reaches_crlb(offset):
    """Statistical but seeded: 2000 ramps at 25 dB; the default must be within 1.2x the CRLB in
    variance (the benchmark measures the 1.1x target with more trials)."""
    snr_db = 25
    f = 140.0 + offset
    x = tones(f, batch=2000, post_fft_snr_db=snr_db, seed=int(offset * 100))
    k = np.full(2000, int(np.floor(f + 0.5)))
    err = estimate(x, k, window="hann") - f
    ratio = np.mean(err**2) / crlb_freq_var_post_fft(10 ** (snr_db / 10), N)
    assert 0.8 < ratio < 1.2
    # and the image-blind three-bin estimator is measurably worse (the test can fail)
    err_j = estimate(x, k, method="jacobsen", window="hann") - f
    assert np.mean(err_j**2) > 1.5 * np.mean(err**2)
