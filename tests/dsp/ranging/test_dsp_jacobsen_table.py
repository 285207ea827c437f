"""The Jacobsen/Candan correction table r(delta) built from the windows' closed-form DTFT (sums of
shifted Dirichlet kernels) against the direct DTFT sum over the window samples, and the cached
geometry of FrameDsp (§2.1: sub-bin refinement of the beat frequency, eq. 2-1)."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.dsp.ranging import estimators as est
from lidard.dsp.frame import FrameDsp
from lidard.dsp.spectrum.window import WINDOW_NAMES, get_window


def _direct_r(window: str, n: int, zero_pad: int, delta: np.ndarray) -> np.ndarray:
    """r(delta) of a unit complex tone by summing w[t] exp(j 2 pi (delta - m) t / (n zero_pad))."""
    w = get_window(window, n)
    t = np.arange(n)
    cols = [np.exp(2j * np.pi * np.outer(delta - m, t) / (n * zero_pad)) @ w for m in (-1, 0, 1)]
    xm, x0, xp = cols
    return np.real((xm - xp) / (2 * x0 - xm - xp))


@pytest.mark.parametrize("window", WINDOW_NAMES)
@pytest.mark.parametrize("n,zero_pad", [(8, 1), (17, 2), (64, 1), (255, 4), (1000, 1), (1000, 2)])
def test_table_matches_the_direct_dtft_sum(window, n, zero_pad):
    r_tab, d_tab = est._jacobsen_table(window, n, zero_pad)
    assert r_tab.size > 100 and np.all(np.diff(r_tab) > 0)  # single-valued inverse
    assert d_tab[0] < 0 < d_tab[-1]
    np.testing.assert_allclose(r_tab, _direct_r(window, n, zero_pad, d_tab), rtol=0, atol=1e-10)


@pytest.mark.parametrize("window", WINDOW_NAMES)
def test_long_record_table_is_exact_at_sampled_offsets(window):
    # a 150 m scan has records of tens of thousands of samples; check a few offsets directly
    n = 48_000
    r_tab, d_tab = est._jacobsen_table(window, n, 1)
    pick = np.linspace(0, d_tab.size - 1, 9).astype(int)
    np.testing.assert_allclose(r_tab[pick], _direct_r(window, n, 1, d_tab[pick]), rtol=0, atol=1e-9)


def test_rectangular_table_is_candans_closed_form():
    # Candan (2011): for the rectangular window r = tan(pi delta/N) / tan(pi/N) exactly
    n = 32
    r_tab, d_tab = est._jacobsen_table("rectangular", n, 1)
    np.testing.assert_allclose(r_tab, np.tan(np.pi * d_tab / n) / np.tan(np.pi / n), rtol=0, atol=1e-12)


def test_dirichlet_kernel_at_its_removable_singularity():
    n = 16
    x = np.array([0.0, 1e-13, 16.0, 0.5])
    t = np.arange(n)
    want = np.exp(-2j * np.pi * np.outer(x, t) / n).sum(axis=1)
    np.testing.assert_allclose(est._dirichlet(x, n), want, rtol=0, atol=1e-9)


def test_jacobsen_estimator_recovers_offsets_on_a_long_record():
    rng = np.random.default_rng(3)
    n = 20_000
    k = rng.integers(100, 5000, 8)
    d = rng.uniform(-0.5, 0.5, 8)
    t = np.arange(n)
    x = np.cos(2 * np.pi * (k + d)[:, None] * t / n + rng.uniform(0, 2 * np.pi, (8, 1)))
    got = est.estimate(x, k, method="jacobsen", window="hann")
    # noise-free: only the real tone's image biases the three-bin ratio (~1/(2 pi k) bins at worst)
    np.testing.assert_allclose(got, k + d, rtol=0, atol=2e-3)


def test_frame_dsp_builds_its_range_fft_once():
    dsp = FrameDsp(ramp_samples=400, fs_hz=5e6, chirp_rate_hz_per_s=1e14, wavelength_m=1.55e-6,
                   max_range_m=2.0)
    assert dsp.rfft is dsp.rfft
    lo, hi = dsp.bin_range
    # gate top: 2 gamma R / c plus the Doppler allowance, in bins of fs / n_used
    f_hi = 2 * 1e14 * 2.0 / 299_792_458.0 + 2 * 5.0 / 1.55e-6
    assert hi == min(int(np.ceil(f_hi / (5e6 / dsp.n_used))) + 2, dsp.n_used // 2)
    assert lo == 0
    rng = np.random.default_rng(0)
    t = np.arange(800) / 5e6
    beat = 100 * np.cos(2 * np.pi * 1.2e6 * t) + rng.normal(0, 1, (3, 2, 800))
    r1 = dsp.process(beat)
    r2 = dsp.process(beat)  # the cached geometry gives the same answer on the next batch
    np.testing.assert_array_equal(r1.range_m, r2.range_m)
    assert r1.present[:, 0].all()
    # a 1.2 MHz beat of a static target is at c f / (2 gamma) = 1.799 m
    np.testing.assert_allclose(r1.range_m[:, 0], 299_792_458.0 * 1.2e6 / 2e14, atol=2e-3)


@pytest.mark.parametrize("rows,n,k", [(1, 8, 3), (61, 360, 19), (200, 360, 19), (7, 12_000, 21)])
def test_blocked_moment_product_equals_the_plain_product(rows, n, k):
    rng = np.random.default_rng(rows + n)
    a = rng.normal(size=(rows, n))
    b = rng.normal(size=(n, k))
    want = np.einsum("ij,jk->ik", a, b)  # no BLAS: an independent summation
    got = est._small_gemm(a, b)
    assert got.shape == (rows, k)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.sqrt(n))
