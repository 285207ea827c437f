"""The windows and the analytic signal are built with numpy (scipy.signal stays off the scan path's
start-up): their samples against scipy.signal's, and against what they must be by definition."""

import numpy as np
import pytest
import scipy.signal as ss

from lidard.dsp.spectrum.instfreq import hilbert
from lidard.dsp.spectrum.window import DspInputError, get_window

SCIPY = {"rectangular": "boxcar", "hann": "hann", "blackmanharris": "blackmanharris"}


@pytest.mark.parametrize("name", sorted(SCIPY))
@pytest.mark.parametrize("n", [2, 3, 8, 255, 1190, 4761])
@pytest.mark.parametrize("symmetric", [False, True])
def test_windows_are_scipys(name, n, symmetric):
    w = get_window(name, n, symmetric=symmetric)
    assert np.max(np.abs(w - ss.get_window(SCIPY[name], n, fftbins=not symmetric))) < 1e-15
    assert not w.flags.writeable


def test_periodic_window_is_one_period_and_symmetric_one_has_equal_ends():
    n = 64
    for name in ("hann", "blackmanharris"):
        p = get_window(name, n)
        # periodic: the n + 1 point symmetric window without its last sample
        assert np.allclose(p, get_window(name, n + 1, symmetric=True)[:-1], atol=1e-15)
        s = get_window(name, n, symmetric=True)
        assert np.allclose(s, s[::-1], atol=1e-15) and s.max() <= 1.0 + 1e-15
    assert get_window("hann", n)[0] == 0.0 and get_window("hann", n)[n // 2] == pytest.approx(1.0)
    with pytest.raises(DspInputError, match="hamming"):
        get_window("hamming", n)


@pytest.mark.parametrize("n", [7, 8, 1000, 1001])
def test_analytic_signal_of_a_tone_is_its_complex_exponential(n):
    k, phi = min(5, (n - 1) // 2), 0.3   # whole periods below Nyquist: the analytic signal is exact
    t = np.arange(n)
    z = hilbert(np.cos(2 * np.pi * k * t / n + phi))
    assert np.max(np.abs(z - np.exp(1j * (2 * np.pi * k * t / n + phi)))) < 1e-12


def test_analytic_signal_is_scipys_along_any_axis():
    x = np.random.default_rng(3).normal(size=(3, 5, 12))
    for axis in (0, 1, 2, -1):
        assert np.allclose(hilbert(x, axis=axis), ss.hilbert(x, axis=axis), atol=1e-13)
    with pytest.raises(ValueError, match="real"):
        hilbert(x + 1j)
