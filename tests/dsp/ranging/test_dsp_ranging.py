"""The joint model of a pixel's returns (lidard.dsp.ranging) against the Cramer-Rao bound, the
chi-square law of its model-order test, and through the frame DSP on pixels drawn from the tone model
(a static pair of returns on both ramps, eq. 2-1; the scan's three-segment chirp where it matters)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from lidard.dsp.ranging.crlb import crlb_freq_var, crlb_tones_freq_var
from lidard.dsp.ranging.estimators import estimate
from lidard.dsp.frame import FrameDsp
from lidard.dsp.detect.gate import PointFlag
from lidard.dsp.spectrum.rangefft import C_M_PER_S, RangeFFT
from lidard.dsp.ranging.lines import lines, render
from lidard.dsp.ranging.order import cell_noise, median_last, order_statistic, unresolved
from lidard.dsp.ranging.tones import refine_joint

GAMMA = 8.6e9 / 80e-6
DSP = FrameDsp(ramp_samples=400, fs_hz=5e6, chirp_rate_hz_per_s=GAMMA, wavelength_m=1.55e-6,
               max_range_m=2.0, max_speed_mps=0.4)
CELL_M = DSP.range_resolution_m          # one bin of the used ramp: 19.4 mm


def _tones(rng, n_pix, n_rec, n, f, amps, sigma):
    t = np.arange(n)
    ph = rng.uniform(0, 2 * np.pi, (n_pix, n_rec, len(f)))
    x = sum(a * np.cos(2 * np.pi * fk[:, None, None] * t / n + ph[..., k:k + 1])
            for k, (fk, a) in enumerate(zip(f, amps)))
    return x + sigma * rng.standard_normal((n_pix, n_rec, n)), ph


@pytest.mark.parametrize("sep", [2.0, 3.0])
def test_joint_refinement_is_unbiased_and_at_the_two_tone_bound(sep):
    rng = np.random.default_rng(1)
    n, n_pix, n_rec, sigma = 512, 400, 2, 1.0          # per-sample SNR 0.5 (-3 dB), post-FFT ~21 dB
    f1 = 100 + rng.uniform(0, 1, n_pix)
    f2 = f1 + sep
    x, ph = _tones(rng, n_pix, n_rec, n, (f1, f2), (1.0, 1.0), sigma)
    # the one-tone estimator, each tone alone (the other's leakage biases it) as the start
    pb = np.broadcast_to(np.stack([np.rint(f1), np.rint(f2)], -1)[:, None, :], (n_pix, n_rec, 2)).astype(int)
    start = estimate(x, pb, method="newton").mean(axis=1)
    got = refine_joint(x, start, np.ones((n_pix, 2), bool))
    err = got - np.stack([f1, f2], -1)
    bound = np.mean([crlb_tones_freq_var([f1[i], f2[i]], np.ones((n_rec, 2)), ph[i], n, sigma) for i in range(40)],
                    axis=0)
    rmse = np.sqrt(np.mean(err ** 2, axis=0))
    assert np.all(rmse < 1.15 * np.sqrt(bound))
    # bias: within 3 standard errors of zero (the one-tone start is off by the leakage, ~0.01-0.04 bin)
    assert np.all(np.abs(err.mean(axis=0)) < 3 * rmse / np.sqrt(n_pix))


def test_two_tone_bound_is_the_one_tone_bound_for_one_tone_and_grows_when_they_close_in():
    one = crlb_tones_freq_var([100.3], [[1.0]], [[0.2]], 1000, 0.1)[0]
    assert one == pytest.approx(crlb_freq_var(0.5 / 0.1 ** 2, 1000, real=True), rel=2e-3)
    far = crlb_tones_freq_var([100.3, 106.3], [[1.0, 1.0]], [[0.2, 1.0]], 1000, 0.1)
    near = crlb_tones_freq_var([100.3, 100.8], [[1.0, 1.0]], [[0.2, 1.0]], 1000, 0.1)
    assert np.all(far < 1.05 * one) and np.all(near > 4 * one)


def test_model_order_statistic_follows_its_chi_square_law_on_one_tone():
    # one tone in white noise at a moderate SNR (the model error floor out of play): the statistic's
    # flag rate at a stated level is that level (binomial 4-sigma band)
    rng = np.random.default_rng(2)
    n, n_pix, n_rec = 256, 3000, 2
    f = rng.uniform(40, 90, n_pix)
    x, _ = _tones(rng, n_pix, n_rec, n, (f,), (1.0,), 1.0)
    rf = RangeFFT(n, 5e6, GAMMA, window="hann")
    spec = rf(x)
    p = spec.real ** 2 + spec.imag ** 2
    start = estimate(x, np.broadcast_to(np.rint(f)[:, None], (n_pix, n_rec)).astype(int), method="newton").mean(1)
    fj = refine_joint(x, start[:, None], np.ones((n_pix, 1), bool))
    idx = np.rint(fj).astype(int)
    for level in (0.05, 0.2):
        flag = unresolved(spec, idx, fj, np.ones((n_pix, 1), bool), cell_noise(p), level=level, window="hann",
                          n_samples=n)
        sd = np.sqrt(level * (1 - level) / n_pix)
        assert abs(flag.mean() - level) < 4 * sd + 0.01, (level, flag.mean())
    stat, dof, _, _ = order_statistic(spec, idx, fj, np.ones((n_pix, 1), bool), cell_noise(p), window="hann",
                                      n_samples=n)
    assert dof[0, 0] == 2 * (7 - 1) * n_rec - 1
    # its mean: the degrees of freedom (within 5 %)
    assert np.mean(stat) == pytest.approx(dof[0, 0], rel=0.05)
    assert np.mean(stat > chi2.isf(0.01, dof[0, 0])) < 0.02


def test_median_is_numpys_median():
    rng = np.random.default_rng(5)
    for n in (361, 360, 7, 2):
        p = rng.exponential(size=(3, 4, n))
        np.testing.assert_array_equal(median_last(p), np.median(p, axis=-1))


def _pixels(ranges_m, amps, snr_db, seed, dsp=DSP, velocity=None):
    """Pixels of static (or moving) returns from the tone model (lidard.dsp.ranging.lines), one record
    each, the strongest at post-FFT SNR ``snr_db`` (rectangular, on-bin: N A^2 / (4 sigma^2))."""
    rng = np.random.default_rng(seed)
    r = np.asarray(ranges_m, dtype=float)
    v = np.zeros_like(r) if velocity is None else np.broadcast_to(velocity, r.shape)
    ln = lines(r, v, chirp_rate_hz_per_s=dsp.chirp_rate_hz_per_s, wavelength_m=dsp.wavelength_m)
    a = np.asarray(amps, dtype=float)
    x = render(ln, a, rng.uniform(0, 2 * np.pi, r.shape + (3,)), fs_hz=dsp.fs_hz, ramp_samples=dsp.ramp_samples,
               cw_samples=dsp.cw_samples)
    sigma = a.max() * np.sqrt(dsp.n_used / (4 * 10 ** (snr_db / 10)))
    return dsp.process((x + sigma * rng.standard_normal(x.shape))[:, None, :])


def test_one_return_is_flagged_at_about_the_stated_level():
    rng = np.random.default_rng(1)
    d = rng.uniform(0.8, 1.8, 400)
    res = _pixels(d[:, None], np.ones((400, 1)), 35.0, seed=2)
    first = res.present & (np.cumsum(res.present, axis=1) == 1)
    assert first.sum() == 400
    # two ramps, each flagged with probability order_level by noise: a few in 400 at most
    assert np.count_nonzero(res.flags[first] & PointFlag.UNRESOLVED) <= 4
    assert np.abs(res.range_m[first] - d).max() < 1e-3


@pytest.mark.parametrize("ratio", [1.0, 0.5, 0.3])
def test_two_returns_a_cell_apart_are_never_two_made_up_points(ratio):
    rng = np.random.default_rng(3)
    d = rng.uniform(0.8, 1.6, 200)
    res = _pixels(np.stack([d, d + CELL_M], axis=1), np.tile([1.0, ratio], (200, 1)), 35.0, seed=0)
    assert not np.any(res.valid & res.present)
    assert np.all((res.flags[res.present] & PointFlag.UNRESOLVED) != 0)


@pytest.mark.parametrize("sep_cells", [2.0, 3.0, 4.5])
def test_two_returns_two_to_five_cells_apart_are_two_clean_points(sep_cells):
    # a pane 40-90 mm in front of a wall: both surfaces valid, each within 4x its one-tone bound
    rng = np.random.default_rng(8)
    d = rng.uniform(0.8, 1.4, 100)
    ranges = np.stack([d, d + sep_cells * CELL_M], axis=1)
    res = _pixels(ranges, np.tile([0.7, 1.0], (100, 1)), 35.0, seed=9)
    two = (res.present & res.valid).sum(axis=1) == 2
    assert two.mean() >= 0.95
    got = np.sort(np.where(res.present & res.valid, res.range_m, np.nan), axis=1)[two]
    ranges = ranges[two]
    # one-tone bound on the weaker return's range (both ramps averaged): sigma_R = c sigma_f / (2 gamma)
    snr = 0.7 ** 2 * 10 ** 3.5 * 4 / DSP.n_used / 2            # per-sample SNR of the weaker (real tone)
    sigma_r = C_M_PER_S / (2 * GAMMA) * np.sqrt(crlb_freq_var(snr, DSP.n_used, real=True, fs_hz=DSP.fs_hz) / 2)
    err = got - ranges
    assert np.abs(err).max() < 6 * sigma_r
    assert np.abs(err.mean(axis=0)).max() < 1e-4                # leakage bias under 0.1 mm


def test_a_weak_return_beside_a_strong_one_is_found_by_the_grown_model():
    # the scan's three-segment chirp: a pane 12 dB under a wall 3 cells in front of it, at an SNR
    # where the detector misses it on many ramps; the grown model finds it
    dsp = FrameDsp(ramp_samples=3200, fs_hz=40e6, chirp_rate_hz_per_s=GAMMA, wavelength_m=1.55e-6, max_range_m=10.0,
                   max_speed_mps=10.0, cw_samples=3120)
    cell = C_M_PER_S / (2 * 8.6e9)
    ranges = np.tile([5.0, 5.0 + 3 * cell], (100, 1))
    res = _pixels(ranges, np.tile([10 ** (-12 / 20), 1.0], (100, 1)), 32.0, seed=4, dsp=dsp)
    ok = res.present & res.valid
    assert np.mean(ok.sum(axis=1) == 2) >= 0.95
    near = np.where(ok & (np.abs(res.range_m - 5.0) < 0.5 * cell), res.range_m, np.nan)
    assert np.nanmax(np.abs(near - 5.0)) < 3e-3


def test_joint_refinement_of_complex_tones_reaches_the_two_tone_bound():
    # an I/Q receiver's ramps: complex tones, signed frequencies (one of them negative)
    rng = np.random.default_rng(6)
    n, n_pix, sigma = 256, 400, 1.0
    f1 = -20.3 + rng.uniform(0, 1, n_pix)
    f2 = f1 + 2.5
    t = np.arange(n)
    ph = rng.uniform(0, 2 * np.pi, (n_pix, 1, 2))
    x = (np.exp(1j * (2 * np.pi * f1[:, None, None] * t / n + ph[..., :1]))
         + np.exp(1j * (2 * np.pi * f2[:, None, None] * t / n + ph[..., 1:])))
    x = x + sigma * (rng.standard_normal(x.shape) + 1j * rng.standard_normal(x.shape))
    start = np.stack([f1, f2], -1) + rng.uniform(-0.2, 0.2, (n_pix, 2))
    got = refine_joint(x, start, np.ones((n_pix, 2), bool))
    err = got - np.stack([f1, f2], -1)
    bound = np.mean([crlb_tones_freq_var([f1[i], f2[i]], np.ones((1, 2)), ph[i], n, sigma, real=False)
                     for i in range(40)], axis=0)
    assert np.all(np.sqrt(np.mean(err ** 2, axis=0)) < 1.15 * np.sqrt(bound))
    assert np.all(np.abs(err.mean(axis=0)) < 3 * np.sqrt(bound / n_pix))


def test_order_level_is_the_rate_at_which_clean_returns_are_flagged():
    # one return per pixel at 20 dB (the model-error floor out of play): each ramp is flagged with
    # probability order_level, a point when either ramp is: 1 - (1 - level)^2
    import dataclasses

    with pytest.raises(ValueError, match="order_level"):
        dataclasses.replace(DSP, order_level=1.0)
    rng = np.random.default_rng(12)
    d = rng.uniform(0.8, 1.8, 600)
    for level in (0.05, 0.3):
        dsp = dataclasses.replace(DSP, order_level=level)
        res = _pixels(d[:, None], np.ones((600, 1)), 20.0, seed=13, dsp=dsp)
        first = res.present & (np.cumsum(res.present, axis=1) == 1)
        rate = np.mean((res.flags[first] & PointFlag.UNRESOLVED) != 0)
        want = 1 - (1 - level) ** 2
        assert abs(rate - want) < 4 * np.sqrt(want * (1 - want) / first.sum()) + 0.02, (level, rate)


def test_per_ramp_level_squared_times_hypotheses_is_the_point_rate():
    from lidard.dsp.ranging.points import hypotheses_per_cell, ramp_pfa
    m = hypotheses_per_cell(ramp_cell_hz=1e4, band_cells=1000, doppler_max_hz=0.0, static_guard_hz=3e4)
    assert m == pytest.approx(12.0)                       # |f_up - f_dn| < 2 x 30 kHz: 12 cells of 10 kHz
    assert ramp_pfa(1e-6, m) ** 2 * m == pytest.approx(1e-6)
    # a triangle's speed prior: the down line within 2 |f_D|max; never more hypotheses than the band's cells
    assert hypotheses_per_cell(ramp_cell_hz=1e4, band_cells=1000, doppler_max_hz=5e4) == pytest.approx(20.0)
    assert hypotheses_per_cell(ramp_cell_hz=1e4, band_cells=100, doppler_max_hz=6e6) == pytest.approx(100.0)
    with pytest.raises(ValueError, match="too high"):
        ramp_pfa(0.09, 1.0)
    with pytest.raises(ValueError, match="pfa"):
        ramp_pfa(0.0, 10.0)


@pytest.mark.slow
def test_noise_only_pixels_give_false_points_at_the_stated_rate():
    """scan.pfa is the rate of valid false points per range cell: ~25 expected in white noise."""
    dsp = FrameDsp(ramp_samples=3200, fs_hz=40e6, chirp_rate_hz_per_s=8.6e9 / 80e-6, wavelength_m=1.55e-6,
                   max_range_m=10.0, max_speed_mps=10.0, pfa=3e-6, max_returns=2, cw_samples=3120)
    lo, hi = dsp.bin_range
    rng = np.random.default_rng(7)
    n_pix = 6000
    valid = 0
    for _ in range(3):
        res = dsp.process(rng.standard_normal((n_pix // 3, 1, 2 * 3200 + 3120)))
        valid += int(np.count_nonzero(res.present & res.valid))
    expected = dsp.pfa * n_pix * (hi - lo + 1)
    assert expected / 2 <= valid <= 2 * expected          # Poisson(26): outside with probability ~2e-3


def test_points_are_cut_back_to_max_returns_valid_first_then_by_snr():
    from lidard.dsp.frame import FrameResult, keep_returns
    present = np.array([[True, True, True, False]])
    valid = np.array([[False, True, True, False]])
    snr = np.array([[40.0, 10.0, 20.0, 50.0]])
    rng_m = np.array([[1.0, 2.0, 3.0, 4.0]])
    res = FrameResult(present=present, valid=valid, range_m=rng_m, velocity_mps=np.zeros((1, 4)), snr_db=snr,
                      intensity_v=np.ones((1, 4)), flags=np.zeros((1, 4), np.uint8))
    out = keep_returns(res, 2)
    assert out.range_m.tolist() == [[3.0, 2.0]]          # both valid points, the stronger first
    assert keep_returns(res, 3).range_m.tolist() == [[3.0, 2.0, 1.0]]   # then the drawn one, not the absent


@pytest.mark.parametrize(("sep", "amps", "sigma"), [(1.5, (1.0, 1.0), 0.3), (2.5, (1.0, 0.3), 1.0),
                                                     (5.0, (0.3, 1.0), 3.0)])
def test_pixels_leaving_the_iterations_once_converged_end_where_full_iterations_end(monkeypatch, sep, amps, sigma):
    """tones.CONVERGED_BINS: a pixel whose Newton step is under it leaves the joint refinement early.
    On separations, amplitude ratios and SNRs other than the resolution table's, the early exit ends
    within a small fraction of the two-tone CRLB of where every pixel iterating to the end ends."""
    from lidard.dsp.ranging import tones
    rng = np.random.default_rng(7)
    n, n_pix, n_rec = 512, 200, 2
    f1 = 80 + rng.uniform(0, 1, n_pix)
    f2 = f1 + sep
    x, ph = _tones(rng, n_pix, n_rec, n, (f1, f2), amps, sigma)
    start = np.stack([f1, f2], -1) + rng.uniform(-0.2, 0.2, (n_pix, 2))
    early = refine_joint(x, start, np.ones((n_pix, 2), bool))
    monkeypatch.setattr(tones, "CONVERGED_BINS", 0.0)      # nobody leaves: every pixel iterates to the end
    full = refine_joint(x, start, np.ones((n_pix, 2), bool))
    bound = np.sqrt(np.mean([crlb_tones_freq_var([f1[i], f2[i]], np.tile(amps, (n_rec, 1)), ph[i], n, sigma)
                             for i in range(20)], axis=0))
    assert np.all(np.abs(early - full).max(axis=0) < 0.01 * bound)
