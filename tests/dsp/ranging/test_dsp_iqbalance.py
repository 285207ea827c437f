"""The coherent receiver's I/Q imbalance (lidard.dsp.ranging.iqbalance) and the frame DSP's I/Q path (issue 14 item 2).

Physics checked against formulas: a hybrid with gain ratio g and quadrature error eps puts an image
of every tone at the mirror frequency with power |1 - c|^2 / |1 + c|^2 (c = g e^{j eps}) of the tone;
the Gram-Schmidt correction removes it; the channels' spectral ratio at a tone is c. On the triangle,
an I/Q receiver gives signed range and velocity in both regimes (Doppler below and above the range
beat: eqs. 2-4..2-7 with signed beats), with no speed prior.
"""

import math

import numpy as np
import pytest

from lidard.dsp.frame import FrameDsp
from lidard.dsp.ranging.iqbalance import correct, estimate_imbalance, image_rejection_db, mirror_images
from lidard.dsp.spectrum.window import DspInputError

C = 299_792_458.0
GAMMA, FS, R, LAM = 1.075e14, 40e6, 4000, 1.55e-6
G, EPS = 10 ** (0.8 / 20), math.radians(6.0)


def tone(f_hz, n, phase=0.3, g=G, eps=EPS, noise=0.0, rng=None, shape=()):
    t = np.arange(n) / FS
    ph = 2 * np.pi * f_hz * t + phase
    i = np.cos(ph) * np.ones(shape + (n,))
    q = g * np.sin(ph + eps) * np.ones(shape + (n,))
    if noise:
        i = i + noise * rng.standard_normal(i.shape)
        q = q + noise * rng.standard_normal(q.shape)
    return i, q


def spectrum_db(z):
    w = np.hanning(z.shape[-1])
    return 20 * np.log10(np.abs(np.fft.fft(z * w)) + 1e-300)


def test_image_power_follows_the_formula_and_correction_removes_it():
    n = 4096
    k = 300                                     # a tone on a bin: leakage-free mirror at -k
    i, q = tone(k * FS / n, n)
    raw = spectrum_db(i + 1j * q)
    measured = raw[-k] - raw[k]
    c = G * complex(math.cos(EPS), math.sin(EPS))
    assert measured == pytest.approx(10 * math.log10(abs(1 - c) ** 2 / abs(1 + c) ** 2), abs=0.01)
    assert image_rejection_db(G, EPS) == pytest.approx(measured, abs=0.01)
    fixed = spectrum_db(correct(i, q, G, EPS))
    assert fixed[-k] - fixed[k] < -150           # rounding and the window's far leakage only
    assert fixed[k] == pytest.approx(20 * math.log10(np.sum(np.hanning(n))), abs=1e-6)  # amplitude 1 kept


def test_estimate_recovers_gain_and_phase_from_noisy_tones_of_both_signs():
    rng = np.random.default_rng(7)
    fs = rng.uniform(-8e6, 8e6, 64)
    fs = fs[np.abs(fs) > 0.3e6]                  # tones of both signs (up and folded ramps)
    recs = [tone(f, 3600, phase=rng.uniform(0, 6.28), noise=0.02, rng=rng) for f in fs]
    fit = estimate_imbalance(np.stack([r[0] for r in recs]), np.stack([r[1] for r in recs]))
    assert fit.tones == len(fs)
    assert abs(fit.gain - G) <= 5 * fit.gain_sem and fit.gain_sem < 2e-3
    assert abs(fit.phase_rad - EPS) <= 5 * fit.phase_sem_rad and fit.phase_sem_rad < 2e-3
    assert fit.irr_before_db == pytest.approx(image_rejection_db(G, EPS), abs=0.3)
    assert fit.irr_after_db < -55


def test_estimate_refuses_records_without_tones():
    rng = np.random.default_rng(1)
    with pytest.raises(DspInputError, match="point the receiver at a target"):
        estimate_imbalance(rng.standard_normal((40, 1024)), rng.standard_normal((40, 1024)))


@pytest.mark.parametrize("gain, phase", [(0.05, 0.0), (1.0, math.radians(50)), (float("nan"), 0.0)])
def test_correct_refuses_an_impossible_imbalance(gain, phase):
    with pytest.raises(DspInputError, match="iq"):
        correct(np.zeros(8), np.zeros(8), gain, phase)


def test_mirror_images_are_the_weak_partner_of_a_mirror_pair():
    n_fft = 1024
    c = n_fft // 2
    index = np.array([[c + 100, c - 100, c + 40], [c + 100, c - 101, c - 300]])
    power = np.array([[1.0, 1e-3, 1e-3], [1.0, 0.5, 1e-3]])
    valid = np.ones_like(index, dtype=bool)
    img = mirror_images(index, power, valid, n_fft)
    # row 0: the -100 detection is 30 dB under +100 -> image; +40 has no partner
    # row 1: -101 is within a bin of the mirror but only 3 dB weaker: a return of its own
    assert img.tolist() == [[False, True, False], [False, False, False]]


def frame(d_m, v_mps, g=G, eps=EPS, noise=0.01, seed=3, n_pix=3, avg=2):
    """I and Q records of a triangle: up tone f_R + 2v/lambda, down tone -f_R + 2v/lambda (synth's sign)."""
    rng = np.random.default_rng(seed)
    t = np.arange(R) / FS
    f_r, f_d = 2 * GAMMA * d_m / C, 2 * v_mps / LAM
    ph = np.concatenate([2 * np.pi * (f_r + f_d) * t + 0.4, 2 * np.pi * (-f_r + f_d) * t + 1.9])
    shape = (n_pix, avg, 2 * R)
    i = np.cos(ph) + noise * rng.standard_normal(shape)
    q = g * np.sin(ph + eps) + noise * rng.standard_normal(shape)
    return i, q


def dsp(**kw):
    kw = {"iq_gain": G, "iq_phase_rad": EPS, **kw}
    return FrameDsp(ramp_samples=R, fs_hz=FS, chirp_rate_hz_per_s=GAMMA, wavelength_m=LAM, max_range_m=10.0,
                    max_speed_mps=10.0, iq=True, max_returns=3, **kw)


@pytest.mark.parametrize("d_m, v_mps", [
    (1.0, 0.0), (0.3, 0.0),                 # static, the near target
    (2.0, 3.0), (2.0, -3.0),                # |f_D| > f_R (folded for a real beat), both signs
    (0.3, 5.0), (0.3, -5.0),                # near and fast
    (8.0, 1.0), (8.0, -9.0),                # far, slow and fast
])
def test_triangle_alone_gives_signed_velocity_in_both_regimes(d_m, v_mps):
    res = dsp().process(*frame(d_m, v_mps)[:1], beat_q=frame(d_m, v_mps)[1])
    for p in range(3):
        sel = res.present[p]
        assert sel.sum() == 1, "one return, no image"
        assert res.valid[p][sel][0]
        assert res.range_m[p][sel][0] == pytest.approx(d_m, abs=2e-4)
        assert res.velocity_mps[p][sel][0] == pytest.approx(v_mps, abs=2e-3)


def test_images_of_an_uncorrected_receiver_are_not_points():
    # the receiver as it comes (no correction): the -23 dB images must not pair into ghosts
    res = dsp(iq_gain=1.0, iq_phase_rad=0.0).process(*frame(1.0, 3.0)[:1], beat_q=frame(1.0, 3.0)[1])
    assert res.present.sum(axis=1).tolist() == [1, 1, 1]
    assert np.allclose(res.range_m[res.present], 1.0, atol=1e-3)
    assert np.allclose(res.velocity_mps[res.present], 3.0, atol=5e-3)


def test_frame_dsp_refuses_what_it_cannot_do():
    i, q = frame(1.0, 0.0)
    with pytest.raises(ValueError, match="beat_q"):
        dsp().process(i)
    with pytest.raises(ValueError, match="iq=False"):
        FrameDsp(ramp_samples=R, fs_hz=FS, chirp_rate_hz_per_s=GAMMA, wavelength_m=LAM,
                 max_range_m=10.0).process(i, beat_q=q)
    with pytest.raises(ValueError, match="constant-frequency"):
        dsp(cw_samples=100)


def test_pairs_are_taken_strongest_first_not_smallest_doppler_first():
    # a weak peak in the up ramp near the down beat (a noise peak, or a far weak return) would pair
    # with the strong return's down beat at "smaller Doppler"; the strong pair must win, the weak
    # up peak then has no partner and is no point
    d_m, v_mps = 2.0, 0.3
    i, q = frame(d_m, v_mps, g=1.0, eps=0.0)
    f_r, f_d = 2 * GAMMA * d_m / C, 2 * v_mps / LAM
    t = np.arange(R) / FS
    weak = 0.1 * np.exp(1j * (2 * np.pi * (f_r - f_d + 200e3) * t + 0.7))   # -20 dB
    i[..., :R] += weak.real
    q[..., :R] += weak.imag
    res = dsp(iq_gain=1.0, iq_phase_rad=0.0).process(i, beat_q=q)
    assert res.present.sum(axis=1).tolist() == [1, 1, 1]
    assert np.allclose(res.range_m[res.present], d_m, atol=1e-3)
    assert np.allclose(res.velocity_mps[res.present], v_mps, atol=5e-3)
