"""The window's DTFT in closed form (lidard.dsp.spectrum.windowdtft) against its defining sum."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.dsp.spectrum.window import get_window
from lidard.dsp.spectrum.windowdtft import _window_dtft_bins, _window_dtft_grid


def _direct(window: str, n: int, x: np.ndarray) -> np.ndarray:
    """sum_t w[t] exp(-j 2 pi x t / n), the definition, in extended precision where the platform has it."""
    t = np.arange(n, dtype=np.longdouble)
    w = get_window(window, n).astype(np.longdouble)
    ang = -2 * np.pi * np.multiply.outer(np.asarray(x, dtype=np.longdouble).ravel(), t) / n
    out = (np.cos(ang) @ w).astype(np.float64) + 1j * (np.sin(ang) @ w).astype(np.float64)
    return out.reshape(np.shape(x))


@pytest.mark.parametrize("window", ["hann", "rectangular", "blackmanharris"])
@pytest.mark.parametrize("n", [64, 65, 360])
def test_points_equal_the_defining_sum(window, n):
    rng = np.random.default_rng(n)
    # generic points, whole bins (the kernels' removable singularities at multiples of n for some
    # term), points a hair off them, DC, Nyquist and beyond one period
    x = np.concatenate([rng.uniform(-12, 12, 300), np.arange(-6.0, 7.0), np.arange(-6, 7) + 1e-9,
                        [n / 2, -n / 2, n, -n, n + 1, n - 1, 2 * n + 0.25, -n - 2]])
    got = _window_dtft_bins(window, n, x)
    want = _direct(window, n, x)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-10 * np.abs(want).max())


@pytest.mark.parametrize("window", ["hann", "rectangular", "blackmanharris"])
@pytest.mark.parametrize("n,zero_pad,m", [(360, 1, 7), (360, 1, 17), (64, 8, 129), (65, 3, 20), (64, 4, 3)])
def test_grid_equals_the_points(window, n, zero_pad, m):
    """Consecutive cells of a zero-padded spectrum: the same values as point by point, whole bins from
    the start included (where a shifted kernel's denominator vanishes)."""
    rng = np.random.default_rng(m)
    x0 = rng.uniform(-20, 20, (6, 2, 3))
    x0[0, 0] = [-3.0, 2.0, -n - 1.0]          # cells landing on whole bins and on a multiple of n
    got = _window_dtft_grid(window, n, x0, m, zero_pad)
    assert got.shape == x0.shape + (m,)
    want = _window_dtft_bins(window, n, x0[..., None] + np.arange(m) / zero_pad)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-11 * np.abs(want).max())
    np.testing.assert_allclose(got[0, 0], _direct(window, n, x0[0, 0][:, None] + np.arange(m) / zero_pad),
                               rtol=0, atol=1e-10 * np.abs(want).max())


def test_hann_main_lobe_values():
    """Hann's DTFT at 0, +-1 and +-2 bins: n/2, -n/4 (times the kernel's phase) and zero."""
    n = 128
    w = _window_dtft_bins("hann", n, np.array([0.0, 1.0, -1.0, 2.0, -2.0]))
    np.testing.assert_allclose(np.abs(w), [n / 2, n / 4, n / 4, 0, 0], atol=1e-9)
