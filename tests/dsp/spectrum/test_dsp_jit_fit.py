"""The compiled tone-fit kernels (lidard.dsp.spectrum._kernels_fit) against the numpy path they stand in for,
and the frame DSP's scratch and gather shortcuts against the plain computation."""

import numpy as np
import pytest

from lidard.dsp.ranging.iqbalance import ramp_volts
from lidard.dsp.ranging.order import cell_noise
from lidard.dsp.ranging.tones import refine_joint
from lidard.dsp.spectrum import jit
from lidard.dsp.spectrum.windowdtft import _window_dtft_grid

needs_numba = pytest.mark.skipif(jit._compiled() is None, reason="numba is not installed")


def _both(monkeypatch, fn):
    jit.kernels()
    got = fn()
    monkeypatch.setenv("LIDARD_DSP_JIT", "0")
    assert jit.kernels() is None
    want = fn()
    monkeypatch.delenv("LIDARD_DSP_JIT")
    return got, want


@needs_numba
@pytest.mark.parametrize("window", ["hann", "rectangular", "blackmanharris"])
@pytest.mark.parametrize("n,zero_pad,m", [(360, 1, 7), (360, 1, 17), (64, 8, 129), (65, 3, 20), (64, 4, 3)])
def test_the_window_grid_is_the_numpy_grid_bit_for_bit(monkeypatch, window, n, zero_pad, m):
    rng = np.random.default_rng(m + n)
    x0 = rng.uniform(-20, 20, (6, 2, 3))
    x0[0, 0] = [-3.0, 2.0, -n - 1.0]          # whole bins and a multiple of n: the limits' cells
    got, want = _both(monkeypatch, lambda: _window_dtft_grid(window, n, x0, m, zero_pad))
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
        got, want = _both(monkeypatch, lambda: refine_joint(x, start, active))
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
