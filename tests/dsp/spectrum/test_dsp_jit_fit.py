"""The compiled tone-fit kernels (lidard.dsp.spectrum._kernels_fit) against the numpy path they stand in for,
and the frame DSP's scratch and gather shortcuts against the plain computation."""

import numpy as np
import pytest

from lidard.dsp.ranging.iqbalance import ramp_volts
from lidard.dsp.ranging.order import cell_noise
from lidard.dsp.ranging.tones import refine_joint
from lidard.dsp.spectrum import jit
from lidard.dsp.spectrum.windowdtft import _window_dtft_grid
from tests.helpers.jit_ab import compiled_and_numpy

needs_numba = pytest.mark.skipif(jit._compiled() is None, reason="numba is not installed")



@needs_numba
@pytest.mark.parametrize("window", ["hann", "rectangular", "blackmanharris"])
@pytest.mark.parametrize("n,zero_pad,m", [(360, 1, 7), (360, 1, 17), (64, 8, 129), (65, 3, 20), (64, 4, 3)])
def test_the_window_grid_is_the_numpy_grid_bit_for_bit(monkeypatch, window, n, zero_pad, m):
    rng = np.random.default_rng(m + n)
    x0 = rng.uniform(-20, 20, (6, 2, 3))
    x0[0, 0] = [-3.0, 2.0, -n - 1.0]          # whole bins and a multiple of n: the limits' cells
    got, want = compiled_and_numpy(monkeypatch, lambda: _window_dtft_grid(window, n, x0, m, zero_pad))
    assert np.all(np.isfinite(want))
    np.testing.assert_array_equal(got, want)


def _tones(f, amp, n, records, iq, rng, noise=0.0):
    t = np.arange(n)
    phase = rng.uniform(0, 2 * np.pi, (f.shape[0], records, f.shape[1]))
    arg = 2 * np.pi * f[:, None, :, None] * t / n + phase[..., None]
    x = (amp[:, None, :, None] * (np.exp(1j * arg) if iq else np.cos(arg))).sum(axis=2)
    if noise:
        x = x + noise * (rng.standard_normal(x.shape) + (1j * rng.standard_normal(x.shape) if iq else 0))
    return x


@needs_numba
@pytest.mark.parametrize("iq", [False, True])
@pytest.mark.parametrize("records", [1, 3])
def test_the_compiled_joint_refinement_finds_the_tones_the_numpy_path_finds(monkeypatch, iq, records):
    # two tones 1.3 to 4 bins apart (leakage between them), a third slot empty on some pixels; the start
    # off by up to 0.2 bin. Noise-free: both paths land on the true frequencies; with noise, on the
    # same maximum (to the rounding of the sines and the solve, and a step more or less at the
    # convergence threshold: far under any CRLB)
    rng = np.random.default_rng(7 + records + 2 * iq)
    n, p_n = 360, 60
    f1 = rng.uniform(20, 150, p_n)
    f = np.stack([f1, f1 + rng.uniform(1.3, 4.0, p_n), f1 + 40.0], axis=1)
    amp = np.stack([np.ones(p_n), rng.uniform(0.2, 1.0, p_n), np.full(p_n, 0.5)], axis=1)
    active = np.ones((p_n, 3), dtype=bool)
    active[::2, 2] = False
    amp = np.where(active, amp, 0.0)
    start = f + rng.uniform(-0.2, 0.2, f.shape)
    for noise, tol_truth in ((0.0, 1e-4), (0.05, None)):
        x = _tones(f, amp, n, records, iq, rng, noise)
        got, want = compiled_and_numpy(monkeypatch, lambda: refine_joint(x, start, active))
        np.testing.assert_allclose(got[~active], start[~active], rtol=0, atol=0)   # an inactive tone: as given
        assert np.max(np.abs(got - want)) < 1e-7
        if tol_truth is not None:
            assert np.max(np.abs(want - f)[active]) < tol_truth
            assert np.max(np.abs(got - f)[active]) < tol_truth
        else:   # the noisy estimates are still near the truth (a few hundredths of a bin at this SNR)
            assert np.max(np.abs(got - f)[active]) < 0.05


def test_ramp_volts_into_a_buffer_are_the_ramp_volts():
    rng = np.random.default_rng(0)
    codes = rng.integers(-32768, 32768, (5, 3, 100)).astype(np.int16)
    seg = codes[..., 7:67]                                 # a ramp's slice of the records (strided)
    out = np.full(seg.shape, np.nan)
    for lsb in (2.0 ** -16, 1.1e-5):
        got = ramp_volts(seg, lsb, iq=False, down=True, out=out)
        assert got is out
        np.testing.assert_array_equal(got, seg.astype(np.float64) * lsb)
        np.testing.assert_array_equal(got, ramp_volts(seg, lsb, iq=False, down=True))


@pytest.mark.parametrize("n_bins", [181, 401])
def test_the_noise_floor_of_some_pixels_reads_only_theirs(n_bins):
    # an exponential spectrum of mean 2 (noise): the floor near 2; some pixels' floor from the rows given
    rng = np.random.default_rng(n_bins)
    p = 2.0 * rng.exponential(size=(40, 10, n_bins))
    rows = np.array([3, 5, 6, 17, 39])
    np.testing.assert_array_equal(cell_noise(p, rows), cell_noise(p[rows]))
    assert abs(cell_noise(p).mean() - 2.0) < 0.1


@needs_numba
@pytest.mark.parametrize("k_tones", [1, 2])
def test_the_compiled_order_test_and_skirt_search_are_the_numpy_ones(monkeypatch, k_tones):
    # one or two tones 2.5 to 6 bins apart in noise, per-record frequencies (a moving return), an
    # empty slot on some ramps: the model-order statistic, its verdicts and the skirt search's
    # residual power agree with the numpy path to rounding; a planted second tone inside the first's
    # cells (not in the model) is flagged by both
    from lidard.dsp.ranging.order import order_statistic, residual_near, unresolved
    from lidard.dsp.spectrum.rangefft import RangeFFT

    rng = np.random.default_rng(k_tones)
    n, p_n, records = 360, 80, 4
    rf = RangeFFT(n, 5e6, 1.075e14, window="hann")
    f1 = rng.uniform(30, 140, p_n)
    f = np.stack([f1, f1 + rng.uniform(2.5, 6.0, p_n)], axis=1)[:, :k_tones]
    amp = np.stack([np.ones(p_n), rng.uniform(0.3, 1.0, p_n)], axis=1)[:, :k_tones]
    valid = np.ones((p_n, k_tones), dtype=bool)
    if k_tones == 2:
        valid[::3, 1] = False
        amp = np.where(valid, amp, 0.0)
    fr = f[:, None, :] + 0.02 * np.arange(records)[None, :, None]          # the beat moves record by record
    t = np.arange(n)
    phase = rng.uniform(0, 2 * np.pi, fr.shape)
    x = (amp[:, None, :, None] * np.cos(2 * np.pi * fr[..., None] * t / n + phase[..., None])).sum(axis=2)
    x[:10] += 0.6 * np.cos(2 * np.pi * (f1[:10, None, None] + 0.9) * t / n)   # hidden under the first peak
    x += 0.01 * rng.standard_normal(x.shape)
    spec = rf(x)
    index = np.rint(f).astype(np.int64)
    noise = np.full(p_n, 0.01 ** 2 * (rf.window_samples ** 2).sum() / rf.window_samples.sum() ** 2)
    kw = dict(window="hann", n_samples=n)
    got, want = compiled_and_numpy(monkeypatch, lambda: order_statistic(spec, index, fr, valid, noise, **kw))
    for a, b in zip(got, want):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12 * np.nanmax(np.abs(b)), equal_nan=True)
    flags, flags_np = compiled_and_numpy(monkeypatch, lambda: unresolved(spec, index, fr, valid, noise, level=1e-3, **kw))
    np.testing.assert_array_equal(flags, flags_np)
    assert flags_np[:10, 0].all() and flags_np[10:, 0].mean() < 0.1
    (cells, rp), (cells_np, rp_np) = compiled_and_numpy(monkeypatch, lambda: residual_near(spec, index[:, 0], fr, valid, half=8,
                                                                              **kw))
    np.testing.assert_array_equal(cells, cells_np)
    np.testing.assert_allclose(rp, rp_np, rtol=1e-8, atol=1e-12 * rp_np.max())
