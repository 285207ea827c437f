"""The CW spectrum's DC guard (lidard.dsp.ranging.cwhold.CW_GUARD_BINS) derived from the window, and what it protects.

The held (CW) segment carries the receiver's DC: the photocurrent of the local oscillator and of every
return, orders of magnitude above a Doppler beat. In the CW power spectrum that DC is a line at exactly
0 Hz seen through the window: its power in bin k is |W(k)|^2 / |W(0)|^2 of the DC's, W the window's DTFT.
For the periodic Hann window (a three-term cosine sum, main lobe +-2 bins) W(1) = W(0) / 2 and W(k) = 0
for every integer k >= 2: bins 0 and 1 hold the DC (the DC bin and its main lobe), and from bin 2 on
it is gone exactly. The guard must therefore be the main lobe's half width in bins, and a band a
slow mover predicts near DC must not read below it: with a smaller guard the DC is taken for that
mover's CW beat (a false "line", the pair looks confirmed by the hold); with this one it is not, and a
real beat just outside the guard is still seen.
"""

import numpy as np
import pytest

from lidard.dsp.spectrum.windowdtft import _window_dtft_bins
from lidard.dsp.frame import FrameDsp
from lidard.dsp.ranging.cwhold import CW_GUARD_BINS
from lidard.dsp.ranging.threeseg import cw_band_power, cw_front_end, cw_line_threshold, cw_noise, cw_window

FS = 40e6
RAMP, CW = 3200, 3120


def _dsp() -> FrameDsp:
    return FrameDsp(ramp_samples=RAMP, fs_hz=FS, chirp_rate_hz_per_s=8.6e9 / 80e-6, wavelength_m=1.55e-6,
                    max_range_m=2.0, max_speed_mps=10.0, cw_samples=CW)


def _main_lobe_half_width_bins(window: str, n: int) -> int:
    """The first integer bin from which the window's DTFT vanishes at every integer bin (to 1e-12 of
    W(0)): where a line at exactly DC leaves no power in the spectrum's bins."""
    k = np.arange(n // 2 + 1)
    w = np.abs(_window_dtft_bins(window, n, k.astype(float)))
    leaks = np.flatnonzero(w > 1e-12 * w[0])
    return int(leaks.max()) + 1


def test_the_guard_is_the_windows_main_lobe_half_width():
    dsp = _dsp()
    n = cw_window(dsp)[1]
    assert _main_lobe_half_width_bins(dsp.window, n) == CW_GUARD_BINS == 2
    # the DC's share of bin 1 through Hann: a quarter of its power (-6 dB): far above any noise floor
    w = np.abs(_window_dtft_bins(dsp.window, n, np.array([0.0, 1.0])))
    assert (w[1] / w[0]) ** 2 == pytest.approx(0.25, rel=1e-9)


def _cw_spectrum(dc: float, beat_bins: float | None = None, pixels: int = 200, seed: int = 0):
    """The frame's own CW front end on records whose hold carries ``dc`` volts of DC and 0.01 V rms of
    noise, and optionally a 0.05 V CW beat at ``beat_bins`` bins of the CW spectrum."""
    dsp = _dsp()
    rng = np.random.default_rng(seed)
    x = 0.01 * rng.standard_normal((pixels, 1, 2 * RAMP + CW))
    x[..., 2 * RAMP:] += dc
    if beat_bins is not None:
        a, n = cw_window(dsp)
        t = np.arange(2 * RAMP, 2 * RAMP + CW) - a
        x[:, 0, 2 * RAMP:] += 0.05 * np.cos(2 * np.pi * beat_bins * t / n + rng.uniform(0, 6.3, (pixels, 1)))
    return cw_front_end(dsp, x, 1.0)


def _lines_seen(p_cw, df, centre_bins, half_bins, guard):
    """Fraction of pixels where the band [centre +- half] (bins) reads a CW line at pfa 1e-6 over its cells."""
    n = p_cw.shape[0]
    centre = np.full((n, 1), centre_bins * df)
    half = np.full((n, 1), half_bins * df)
    peak, inside = cw_band_power(p_cw, df, centre, half, guard)
    assert not inside.any()
    x = peak / cw_noise(p_cw, 1)[:, None]
    cells = np.ceil(2 * half / df) + 1
    return float(np.mean(x >= cw_line_threshold(1e-6, 1, cells)))


def test_the_guard_keeps_the_dc_from_posing_as_a_slow_movers_cw_beat():
    # the DC of the hold: 0.5 V, against 0.01 V rms of noise (the photocurrent of the LO)
    p_cw, df = _cw_spectrum(dc=0.5)
    # a slow mover predicts its CW beat at 1.5 bins, +-1.5 bins (its band runs into the DC's lobe)
    assert _lines_seen(p_cw, df, 1.5, 1.5, guard=0) == 1.0        # the DC bin itself
    assert _lines_seen(p_cw, df, 1.5, 1.5, guard=1) == 1.0        # the DC's main lobe (-6 dB)
    assert _lines_seen(p_cw, df, 1.5, 1.5, guard=CW_GUARD_BINS) == 0.0


def test_a_real_cw_beat_just_outside_the_guard_is_still_seen():
    p_cw, df = _cw_spectrum(dc=0.5, beat_bins=CW_GUARD_BINS + 0.6)
    assert _lines_seen(p_cw, df, 1.5, 1.5, guard=CW_GUARD_BINS) == 1.0


def test_a_band_wholly_inside_the_guard_is_flagged_not_read():
    p_cw, df = _cw_spectrum(dc=0.5, pixels=4)
    centre = np.full((4, 1), 0.5 * df)
    half = np.full((4, 1), 0.4 * df)
    peak, inside = cw_band_power(p_cw, df, centre, half, CW_GUARD_BINS)
    assert inside.all() and np.all(peak == 0.0)
