"""One refinement per pixel (lidard.dsp.ranging.pixeltone): the maximum-likelihood beat of a return from
all the records of a pixel, against the L-record Cramer-Rao bound, against the mean of per-record
refinements at low SNR, and with a moving return's drifting beat (through the frame DSP too)."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.dsp.frame import FrameDsp
from lidard.dsp.ranging.crlb import crlb_tones_freq_var
from lidard.dsp.ranging.estimators import estimate, pooled_jacobsen
from lidard.dsp.ranging.pixeltone import record_offsets, refine_pixel_tone
from lidard.dsp.spectrum.rangefft import C_M_PER_S, RangeFFT

N, L = 360, 10


def _pixels(rng, snr_db, p_n=1000, drift=0.0, n=N, l_n=L):
    """Real records (P, L, n): one tone at f + offset_l x drift (bins), a random phase per record, at
    post-FFT SNR ``snr_db`` a record (rectangular, on-bin: n A^2 / (4 sigma^2), A = 1)."""
    sigma = np.sqrt(n / (4 * 10 ** (snr_db / 10)))
    f = rng.uniform(60.0, 61.0, p_n)
    fl = f[:, None] + record_offsets(l_n) * drift                                    # (P, L)
    t = np.arange(n)
    x = np.cos(2 * np.pi * fl[..., None] * t / n + rng.uniform(0, 2 * np.pi, (p_n, l_n, 1)))
    return x + sigma * rng.standard_normal(x.shape), f, sigma


def _bound(sigma, n=N, l_n=L):
    """The L-record Cramer-Rao bound on the common frequency (bins^2), amplitude 1 in every record."""
    ph = np.random.default_rng(0).uniform(0, 2 * np.pi, (l_n, 1))
    return float(np.ravel(crlb_tones_freq_var([60.3], np.ones((l_n, 1)), ph, n, sigma))[0])


def _both(x):
    """(the pixel fit, the mean of per-record ``newton`` refinements), both from the averaged spectrum's peak."""
    rf = RangeFFT(x.shape[-1], 1.0, 1.0, window="hann")
    spec = rf(x)
    p = (spec.real ** 2 + spec.imag ** 2).mean(axis=1)
    k = 55 + np.argmax(p[:, 55:67], axis=1)
    start = pooled_jacobsen(spec, k[:, None], window="hann", n_samples=x.shape[-1])[:, 0]
    new = refine_pixel_tone(x, start)[0]
    old = estimate(x, np.broadcast_to(k[:, None], x.shape[:2]), method="newton", window="hann", spectrum=spec).mean(1)
    return new, old


@pytest.mark.parametrize("snr_db", [12.0, 20.0, 30.0])
def test_the_pixel_fit_reaches_the_l_record_bound(snr_db):
    x, f, sigma = _pixels(np.random.default_rng(int(snr_db)), snr_db)
    new, _ = _both(x)
    err = new - f
    ratio = err.var() / _bound(sigma)
    # 1000 pixels: the variance's own spread is ~4.5 %; the bound is reached, not approached
    assert 0.8 < ratio < 1.2
    assert abs(err.mean()) < 3 * np.sqrt(_bound(sigma) / f.size)


def test_at_low_snr_the_pixel_fit_beats_the_mean_of_record_fits():
    # 9 dB a record: one record's Newton is near its threshold (a few outliers a hundred), ten of them
    # summed are not; the mean of ten one-record estimates keeps their outliers
    x, f, sigma = _pixels(np.random.default_rng(9), 9.0, p_n=2000)
    new, old = _both(x)
    b = _bound(sigma)
    assert (new - f).var() / b < 1.4
    assert np.mean(np.abs(new - f) > 5 * np.sqrt(b)) < 0.002
    assert (old - f).var() / b > 2.0                   # the per-record mean: the bound this test sets fails


def test_a_drifting_beat_is_fitted_at_the_common_frequencys_bound():
    # a beat moving 0.12 bin a record (10 m/s on the scan's chirp at 40 MS/s): the pixel's middle
    # frequency unbiased and at the common-frequency bound (the drift is orthogonal to it), the drift found
    rng = np.random.default_rng(4)
    x, f, sigma = _pixels(rng, 20.0, p_n=600, drift=0.12)
    rf = RangeFFT(N, 1.0, 1.0, window="hann")
    spec = rf(x)
    k = 55 + np.argmax((np.abs(spec) ** 2).mean(axis=1)[:, 55:67], axis=1)
    start = pooled_jacobsen(spec, k[:, None], window="hann", n_samples=N)[:, 0]
    fit = refine_pixel_tone(x, start, max_drift=0.13)
    got, drift = fit.freq, fit.drift
    b = _bound(sigma)
    assert abs((got - f).mean()) < 3 * np.sqrt(b / f.size)
    assert (got - f).var() / b < 1.25
    assert np.abs(drift - 0.12).max() < 0.02
    # without the drift in the model the same records give a worse estimate of the same frequency
    common = refine_pixel_tone(x, start).freq
    assert (common - f).var() > 1.5 * (got - f).var()


def test_the_drifts_likelihood_gain_on_a_static_return_is_chi_square_with_one_degree():
    # no drift in the records, a drift allowed: twice the log-likelihood ratio, gain / sigma^2 for real
    # records, is chi-square(1) (mean 1, 1 % past its 1 % quantile): the frame keeps the drift past the
    # model-order level, else fits the common frequency (lidard.dsp.ranging.ramp)
    from scipy.stats import chi2

    x, f, sigma = _pixels(np.random.default_rng(6), 20.0, p_n=3000)
    fit = refine_pixel_tone(x, f + 0.02, max_drift=0.13)
    stat = fit.gain / sigma ** 2
    assert abs(stat.mean() - 1.0) < 0.1                 # 3000 draws: the mean's spread ~0.026
    assert 0.005 < np.mean(stat > chi2.isf(0.01, 1)) < 0.017
    # its common frequency is the one-parameter fit's (the quadratic model's step: within 5 % of the bound's sd)
    one = refine_pixel_tone(x, f + 0.02).freq
    assert np.abs(fit.common - one).max() < 0.05 * np.sqrt(_bound(sigma))


def _fast_returns(seed: int, r_lo: float, r_hi: float, wall_bins: float | None = None):
    """40 pixels of a return receding at 8 m/s in the 10 m/s band (40 MS/s, 3200-sample ramps, the
    three-segment record 238 us long: its beat moves ~0.9 bin over the pixel's 10 records), 25 dB a
    record, through the frame DSP's plain front end; with ``wall_bins`` a static surface that many range
    bins behind it, at 0.3 of its amplitude. (frequencies, detections, the truth's range at the pixel's
    middle record)."""
    fs, ramp, gamma, lam = 40e6, 3200, 8.6e9 / 80e-6, 1.55e-6
    dsp = FrameDsp(ramp_samples=ramp, fs_hz=fs, chirp_rate_hz_per_s=gamma, wavelength_m=lam, max_range_m=2.0,
                   max_speed_mps=10.0, cw_samples=9520 - 2 * ramp)
    rng = np.random.default_rng(seed)
    p_n, v, period = 40, 8.0, 9520 / fs
    r0 = rng.uniform(r_lo, r_hi, p_n)
    t = np.arange(ramp) / fs
    sigma = np.sqrt(dsp.n_used / (4 * 10 ** 2.5))                                      # 25 dB a record
    x = rng.normal(0.0, sigma, (p_n, L, 2 * ramp))
    f_d = -2 * v / lam
    for k, sign in ((0, -1.0), (1, 1.0)):
        t0 = np.arange(L)[:, None] * period + k * ramp / fs
        f0 = 2 * gamma * (r0[:, None, None] + v * t0[None]) / C_M_PER_S + sign * f_d
        ph = 2 * np.pi * (f0 * t + gamma * v / C_M_PER_S * t * t) + rng.uniform(0, 2 * np.pi, (p_n, L, 1))
        x[..., k * ramp:(k + 1) * ramp] += np.cos(ph)
        if wall_bins is not None:
            r_wall = r0 + wall_bins * fs / dsp.n_used * C_M_PER_S / (2 * gamma)
            f_w = 2 * gamma * r_wall[:, None, None] / C_M_PER_S
            x[..., k * ramp:(k + 1) * ramp] += 0.3 * np.cos(2 * np.pi * f_w * t
                                                            + rng.uniform(0, 2 * np.pi, (p_n, L, 1)))
    f, det = dsp._plain_front_end(x, 1.0)
    return f, det, r0 + v * (ramp / fs + 0.5 * (L - 1) * period), gamma


def test_a_fast_return_through_the_frame_dsp_is_one_clean_point_at_its_mid_pixel_range():
    # range from the ramps' beats at the pixel's middle; the model-order test must not read the drift
    # as a second surface
    f, det, r_mid, gamma = _fast_returns(7, 1.2, 1.4)
    for d in det:
        assert d.valid[:, 0].all() and not d.unresolved[:, 0].any()
    fu, fd = f[0][:, 0], f[1][:, 0]
    rng_m = C_M_PER_S * np.abs(fd - fu) / 2 / (2 * gamma)           # folded: |f_D| > f_R at 1.3 m
    assert np.abs(rng_m - r_mid).max() < 0.5e-3                      # ~5 sd of the 0.09 mm spread


def test_a_fast_return_beside_a_far_second_return_keeps_its_drift_model():
    # the fast return with a static second surface 40 range bins behind it on every pixel (a wall
    # behind a moving object): the two share no cells, so the moving one is still fitted with its
    # drift and tested alone; judged jointly with the far one (no drift) it was flagged unresolved
    f, det, r_mid, gamma = _fast_returns(11, 1.0, 1.1, wall_bins=40)
    for d in det:
        assert (d.valid.sum(axis=-1) >= 2).all()                     # both surfaces detected on every ramp
        assert not (d.unresolved & d.valid).any()
    # the moving return is each ramp's stronger detection; its range from the two ramps' beats at
    # the pixel's middle record, as for the lone fast return
    fu, fd = (np.take_along_axis(fr, np.argmax(np.where(d.valid, d.power, -1.0), axis=-1)[:, None], -1)[:, 0]
              for fr, d in zip(f, det))
    rng_m = C_M_PER_S * np.abs(fd - fu) / 2 / (2 * gamma)
    assert np.abs(rng_m - r_mid).max() < 0.5e-3


def test_pooled_jacobsen_is_exact_on_noise_free_records_and_refuses_a_bad_shape():
    rng = np.random.default_rng(2)
    f = rng.uniform(40.0, 41.0, 50)
    t = np.arange(N)
    x = np.exp(2j * np.pi * f[:, None, None] * t / N + 1j * rng.uniform(0, 6, (50, 4, 1))) * rng.uniform(0.5, 2, (50, 4, 1))
    rf = RangeFFT(N, 1.0, 1.0, window="hann", iq=True)
    spec = rf(x)
    k = np.rint(f).astype(np.int64)
    got = pooled_jacobsen(spec, k[:, None], window="hann", n_samples=N, iq=True)[:, 0]
    assert np.abs(got - f).max() < 2e-3                 # the table's resolution
    import lidard.dsp.chain as chain
    from lidard.dsp.detect.cfar import CfarSettings
    with pytest.raises(ValueError, match="pixel start"):
        chain.detect_and_refine(spec[:, 0], lambda i: (x[:, 0], i, None), cfar=CfarSettings(window="hann", iq=True),
                                estimator=None)


def test_the_compiled_record_slopes_give_the_numpy_fit_bit_for_bit(monkeypatch):
    from lidard.dsp.spectrum import jit
    from tests.helpers.jit_ab import compiled_and_numpy

    if jit._compiled() is None:
        pytest.skip("numba is not installed")
    x, f, _ = _pixels(np.random.default_rng(11), 14.0, p_n=200, drift=0.05)
    start = f + np.random.default_rng(12).uniform(-0.2, 0.2, f.size)
    got, want = compiled_and_numpy(monkeypatch, lambda: refine_pixel_tone(x, start, max_drift=0.06))
    # the kernel makes numpy's products and sums in numpy's order from numpy's sines (as newton_real_step)
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


def test_the_estimator_key_selects_the_pixel_fit_or_the_mean_of_record_estimates():
    # newton: one fit per pixel; another estimator: every record refined, their mean (the comparison path)
    gamma = 8.6e9 / 80e-6
    kw = dict(ramp_samples=400, fs_hz=5e6, chirp_rate_hz_per_s=gamma, wavelength_m=1.55e-6, max_range_m=2.0,
              max_speed_mps=0.4)
    ml, mean = FrameDsp(**kw), FrameDsp(**kw, estimator="parabolic")
    assert ml.pixel_ml and not mean.pixel_ml
    rng = np.random.default_rng(5)
    p_n = 300
    f = rng.uniform(60.0, 61.0, p_n)                   # bins of the 360 used samples
    t = np.arange(400) - ml.offset
    sigma = np.sqrt(ml.n_used / (4 * 10 ** 2.0))       # 20 dB a record
    tone = np.cos(2 * np.pi * f[:, None, None] * t / ml.n_used + rng.uniform(0, 2 * np.pi, (p_n, L, 1)))
    x = np.concatenate([tone, tone], axis=-1) + sigma * rng.standard_normal((p_n, L, 800))
    errs = []
    for dsp in (ml, mean):
        got, det = dsp._plain_front_end(x, 1.0)
        assert det[0].valid[:, 0].all()
        errs.append(got[0][:, 0] / dsp.rfft.delta_f - f)
    b = _bound(sigma)
    assert errs[0].var() / b < 1.25                    # the pixel fit at the bound
    assert errs[1].var() / b > 1.5                     # the parabola's mean: a biased, noisier estimate
