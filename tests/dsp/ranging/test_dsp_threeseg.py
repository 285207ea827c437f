"""Three-segment pairing (lidard.dsp.ranging.threeseg): real-receiver magnitudes built from the physics
(up |f_R - f_D|, down |f_R + f_D|, CW |f_D|, f_D = -2 v / lambda), both regimes, several returns."""

import numpy as np
import pytest

from lidard.dsp.frame import FrameDsp
from lidard.dsp.spectrum.rangefft import C_M_PER_S
from lidard.dsp.ranging.threeseg import PairingSettings, pair_three

WL = 1.55e-6
KAPPA = 8.6e9 / 80e-6


def _beats(range_m, v_mps):
    f_r = 2 * KAPPA * np.asarray(range_m) / C_M_PER_S
    f_d = -2 * np.asarray(v_mps) / WL
    return np.abs(f_r - f_d), np.abs(f_r + f_d), np.abs(f_d)


DF = 20e3            # CW bin spacing of the synthetic CW spectra
N_CW = 1000


def _cw_power(*f_d_abs, spread_hz=0.0):
    """A CW power spectrum: noise floor 1, each Doppler beat a 40x peak over +-spread (the held
    segment's relaxation) and its window lobe."""
    p = np.ones(N_CW)
    for f in f_d_abs:
        lo, hi = int((f - spread_hz) // DF) - 1, int((f + spread_hz) // DF) + 2
        p[max(lo, 0):max(hi, 0)] += 40.0
    return p[None, :]


def _pair(fu, fd, p_cw, k=1):
    fu, fd = (np.atleast_2d(x).astype(float) for x in (fu, fd))
    vu, vd = np.ones(fu.shape, bool), np.ones(fd.shape, bool)
    return pair_three((fu, fd), (vu, vd), p_cw, DF,
                      PairingSettings(chirp_rate_hz_per_s=KAPPA, wavelength_m=WL, guard_bins=2, max_targets=k))


@pytest.mark.parametrize("range_m, v", [(0.3, 0.0), (0.3, 4.9), (0.3, -4.9), (1.0, 0.3), (1.0, -0.3),
                                        (1.0, 3.0), (1.0, -3.0), (2.0, 0.2), (2.0, -5.0), (10.0, 10.0)])
def test_single_target_both_regimes(range_m, v):
    fu, fd, fc = _beats(range_m, v)
    rng, vel, ok, seen, _, _ = _pair([[fu]], [[fd]], _cw_power(fc, spread_hz=0.05 * 2 * KAPPA * range_m / C_M_PER_S))
    assert ok[0, 0] and seen[0, 0]
    assert rng[0, 0] == pytest.approx(range_m, abs=1e-9)
    assert vel[0, 0] == pytest.approx(v, abs=1e-9)


def test_swapped_regimes_are_told_apart_by_the_cw_beat():
    # (1 m, folded speed) and (its swapped twin) give the same ramp pair: only the CW beat differs
    fu, fd, fc = _beats(1.0, 3.0)
    f_r = 2 * KAPPA * 1.0 / C_M_PER_S
    twin_range = C_M_PER_S * (2 / WL * 3.0) / (2 * KAPPA)
    twin_v = WL * f_r / 2                   # f_D' = -f_R (same sign as f_D): the beats swap roles
    tu, td, tc = _beats(twin_range, twin_v)
    assert (tu, td) == pytest.approx((fu, fd), rel=1e-9)
    for c, want in ((fc, 1.0), (tc, twin_range)):
        rng, _, ok, _, _, _ = _pair([[fu]], [[fd]], _cw_power(c))
        assert ok[0, 0] and rng[0, 0] == pytest.approx(want, abs=1e-9)


def test_no_cw_evidence_no_point():
    # a ramp pair whose regimes both predict a CW beat where the CW spectrum is flat is not a target
    fu, fd, _ = _beats(1.0, 3.0)
    _, _, ok, seen, _, _ = _pair([[fu]], [[fd]], _cw_power())
    assert not seen.any() and not ok.any()


def test_two_returns_are_paired_consistently():
    a, b, c = _beats(np.array([0.8, 1.7]), np.array([2.5, -1.5]))
    # strongest-first order differs between the spectra: the pairing must not care
    rng, vel, ok, _, _, _ = _pair([a], [b[::-1]], _cw_power(*c), k=2)
    assert ok.all()
    got = sorted(zip(rng[0], vel[0]))
    assert got[0] == pytest.approx((0.8, 2.5), abs=1e-9)
    assert got[1] == pytest.approx((1.7, -1.5), abs=1e-9)


def test_near_the_regime_boundary_is_drawn_but_not_valid():
    # |f_D| within the CW spread of f_R: both regimes fit the CW spectrum; the point is flagged
    f_r = 2 * KAPPA * 1.0 / C_M_PER_S
    v = -WL * 0.97 * f_r / 2
    fu, fd, fc = _beats(1.0, v)
    _, _, ok, seen, _, _ = _pair([[fu]], [[fd]], _cw_power(fc, spread_hz=0.05 * f_r))
    assert seen[0, 0] and not ok[0, 0]


def _records(dsp, range_m, v, amp=0.05, noise=1e-4, seed=0):
    """Ideal real beats of one target in up, down and CW segments (the CW's Doppler tone alone)."""
    r, fs = dsp.ramp_samples, dsp.fs_hz
    fu, fd, fc = _beats(range_m, v)
    rng = np.random.default_rng(seed)
    t_r, t_c = np.arange(r) / fs, np.arange(dsp.cw_samples) / fs
    x = np.concatenate([np.cos(2 * np.pi * fu * t_r + 0.3), np.cos(2 * np.pi * fd * t_r + 1.1),
                        np.cos(2 * np.pi * fc * t_c + 2.0)]) * amp
    return (x + noise * rng.standard_normal(x.size))[None, None, :]


@pytest.mark.parametrize("range_m, v", [(0.3, 0.0), (0.3, 5.0), (1.2, -2.0), (1.9, -5.0), (1.0, 0.2)])
def test_frame_dsp_three_segment_sub_bin(range_m, v):
    fs, ramp_s, cw_s = 20e6, 80e-6, 78e-6
    dsp = FrameDsp(ramp_samples=int(fs * ramp_s), fs_hz=fs, chirp_rate_hz_per_s=KAPPA, wavelength_m=WL,
                   max_range_m=2.0, max_speed_mps=10.0, cw_samples=int(fs * cw_s), max_returns=2)
    res = dsp.process(_records(dsp, range_m, v))
    assert res.valid[0].sum() == 1
    k = int(np.argmax(res.valid[0]))
    assert res.range_m[0, k] == pytest.approx(range_m, abs=1e-3)
    assert res.velocity_mps[0, k] == pytest.approx(v, abs=0.01)


def test_cw_window_is_fft_friendly_and_ends_with_the_record():
    # the CW FFT's length: the largest even 2-3-5-smooth size that skips at least the first quarter
    from lidard.dsp.ranging.threeseg import CW_SKIP_FRACTION, _smooth_at_most, cw_window

    def smooth(m):
        for p in (2, 3, 5):
            while m % p == 0:
                m //= p
        return m == 1
    for n in range(4, 1200):
        m = _smooth_at_most(n)
        assert m <= n and m % 2 == 0 and smooth(m)
        assert not any(smooth(k) for k in range(m + 2, n + 1, 2))
    dsp = FrameDsp(ramp_samples=20000, fs_hz=250e6, chirp_rate_hz_per_s=KAPPA, wavelength_m=WL, max_range_m=100.0,
                   cw_samples=19500)
    a, n = cw_window(dsp)
    assert a + n == 2 * 20000 + 19500                   # ends with the record
    assert a >= 2 * 20000 + int(19500 * CW_SKIP_FRACTION)
    assert n == 14580                                   # 2^2 3^6 5 (not 14,624 = 2^5 x 457)


def test_a_weak_noise_peak_does_not_take_a_true_peak_from_its_partner():
    # a target at 0.64 m receding at 0.19 m/s (not folded): up |f_R - f_D|, down |f_R + f_D|, CW |f_D|;
    # a noise peak in the down ramp within a CW bin of the up beat reads as v ~ 0, which needs no CW
    # evidence and so needs less motion than the true pair; 20 dB weaker than the up peak, the true
    # partner (one amplitude on both ramps) is far the likelier: the assignment takes it
    fu, fd, fc = _beats(0.64, 0.19)
    up = np.array([[fu, 0.0]])
    down = np.array([[fd, fu + 0.3 * DF]])
    vu, vd = np.array([[True, False]]), np.array([[True, True]])
    p_cw = _cw_power(fc)
    pairing = PairingSettings(chirp_rate_hz_per_s=KAPPA, wavelength_m=WL, guard_bins=2, max_targets=2)
    r0, v0, ok0, *_ = pair_three((up, down), (vu, vd), p_cw, DF, pairing)
    assert ok0[0, 0] and abs(v0[0, 0]) < 0.05            # without the powers: equally likely, least motion
    snr = (np.array([[1000.0, 0.0]]), np.array([[900.0, 10.0]]))
    r1, v1, ok1, *_ = pair_three((up, down), (vu, vd), p_cw, DF, pairing, snr=snr)
    assert ok1[0, 0] and r1[0, 0] == pytest.approx(0.64, abs=1e-6) and v1[0, 0] == pytest.approx(0.19, abs=1e-6)
    assert not ok1[0, 1]
