"""Laser phase-noise compensation from the monitor MZI (dissertation §2.3, Fig. 2-6, Fig. 2-7).

The monitor MZI (delay tau_m) sees the laser phase difference ``Delta phi_m(t) = phi(t) - phi(t - tau_m)``
on top of its deterministic chirp phase. A target at round trip ``tau = M tau_m`` sees
``phi(t) - phi(t - M tau_m) = sum_{m<M} Delta phi_m(t - m tau_m)`` -- exactly, whatever the chirp. So:

1. Hilbert phase of the monitor beat, minus its best-fit line per ramp (the linear chirp part):
   ``delta(t)`` = phase noise + whatever nonlinearity the chirp still has. Removing only a line is
   deliberate: a low-order smooth fit would also remove the slow part of the phase noise, which the
   sum over M multiplies by M; the line itself only shifts the compensated tone's frequency by
   M times the MZI beat, i.e. back to where the target is. Residual chirp nonlinearity is then
   compensated too (it adds up over M exactly like the noise).
2. The analytic LiDAR beat is multiplied by ``exp(-j sum_{m<M} delta(t - m tau_m))`` (no effect on the
   Doppler shift, so velocity survives, §2.3).
3. Every range uses its nearest M: the spectrum is computed once per M and the bins whose beat
   frequency is nearest ``M f_mzi`` (``f_mzi`` = the MZI beat frequency, measured) are stitched.

The sign of the chirp does not matter: on a ramp where the optical frequency falls, both Hilbert
phases (MZI and LiDAR) are the negatives of the optical ones, consistently.

Pure numpy/scipy: no I/O, no clock, no logging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import get_window, hilbert

from .instfreq import analytic_phase, check_finite_array, check_positive


@dataclass(frozen=True)
class MziPhaseNoise:
    delta_rad: np.ndarray       # phase-noise (+ nonlinearity) estimate per sample of the ramp
    f_mzi_hz: float             # slope of the best-fit line / 2 pi: the MZI beat frequency
    valid: np.ndarray           # samples away from the Hilbert edge transients


def mzi_phase_noise(mzi, *, fs_hz: float, edge_s: float) -> MziPhaseNoise:
    """Estimate Delta phi_m(t) from one ramp of the monitor-MZI beat (1-D, one ramp)."""
    x = check_finite_array("mzi", mzi, ndim=(1,))
    fs_hz = check_positive("fs_hz", fs_hz)
    n_edge = int(math.ceil(edge_s * fs_hz))
    if 2 * n_edge + 16 > x.size:
        raise ValueError(f"mzi: {x.size} samples are too few for edge_s={edge_s!r} at fs_hz={fs_hz!r}")
    # A real beat carries the phase noise only as far as its positive and negative frequency
    # sidebands do not overlap: keep |f - f_mzi| < f_mzi (Bedrosian), otherwise the broadband
    # phase noise folds through 0 Hz and the Hilbert phase is wrong. The noise beyond that is lost,
    # which is why a longer monitor delay (higher beat frequency) compensates better.
    spec = np.abs(np.fft.rfft((x - x.mean()) * np.hanning(x.size)))
    f_peak = float(np.argmax(spec[1:]) + 1) * fs_hz / x.size
    xb = _band(x - x.mean(), fs_hz, f_peak, 0.9 * f_peak)
    phase, _ = analytic_phase(xb, pad=n_edge)
    valid = np.zeros(x.size, dtype=bool)
    valid[n_edge:x.size - n_edge] = True
    k = np.arange(x.size, dtype=np.float64)
    # A 2 pi slip (where the band-limited beat fades) is harmless in exp(-j sum delta) but tilts a
    # least-squares line, and every compensated tone moves by M times the tilt: the slope is the
    # median of the phase advances over windows of 1/8 of the ramp, which a few slips cannot move
    # much (many slips still can: see the known weakness in the tests).
    kv, pv = k[valid], phase[valid]
    lag = max(1, kv.size // 8)
    slope = float(np.median((pv[lag:] - pv[:-lag]) / lag))
    r = pv - slope * kv
    icpt = float(np.median(r - 2 * np.pi * np.rint((r - np.median(r)) / (2 * np.pi))))
    delta = phase - (slope * k + icpt)
    delta[~valid] = 0.0
    return MziPhaseNoise(delta_rad=delta, f_mzi_hz=float(slope * fs_hz / (2 * np.pi)), valid=valid)


def _band(x: np.ndarray, fs_hz: float, center_hz: float, half_width_hz: float) -> np.ndarray:
    """Keep center +- half_width (skirts 10 % wide), zero-phase."""
    spec = np.fft.rfft(x)
    f = np.fft.rfftfreq(x.size, d=1.0 / fs_hz)
    center = center_hz
    dist = np.abs(f - center)
    edge = 0.1 * half_width_hz
    mask = np.clip((half_width_hz + edge - dist) / edge, 0.0, 1.0)
    mask = 0.5 * (1 - np.cos(np.pi * mask))
    return np.fft.irfft(spec * mask, n=x.size)


def _delayed(x: np.ndarray, shift: float) -> np.ndarray:
    """x(k - shift), zero before the start; linear interpolation for a fractional shift."""
    n = x.size
    if abs(shift - round(shift)) < 1e-6:
        s = int(round(shift))
        out = np.zeros(n)
        if s < n:
            out[s:] = x[:n - s]
        return out
    k = np.arange(n) - shift
    return np.interp(k, np.arange(n), x, left=0.0, right=0.0)


def cumulative_phase_noise(delta_rad, m_max: int, delay_samples: float):
    """Yield (M, sum_{m<M} delta(t - m tau_m)) for M = 0..m_max."""
    s = np.zeros(np.asarray(delta_rad).size)
    yield 0, s.copy()
    for m in range(m_max):
        s += _delayed(np.asarray(delta_rad, dtype=np.float64), m * delay_samples)
        yield m + 1, s.copy()


@dataclass(frozen=True)
class CompensatedSpectrum:
    """One-sided (positive beat frequency) magnitude spectra of a ramp, before and after compensation.

    ``freq_hz``: bin frequencies; ``raw``/``comp``: |FFT| of the windowed analytic beat;
    ``m_of_bin``: which M was used for each bin; ``f_mzi_hz``: measured MZI beat frequency;
    ``start``: first sample of the analysis window (earlier samples lack the delayed MZI history).
    """

    freq_hz: np.ndarray
    raw: np.ndarray
    comp: np.ndarray
    m_of_bin: np.ndarray
    f_mzi_hz: float
    start: int

    def peak_gain_db(self, f_hz: float, search_bins: int = 3) -> float:
        """Peak (max |FFT| within +-search_bins of f_hz) after over before compensation, dB (amplitude)."""
        i = int(np.argmin(np.abs(self.freq_hz - f_hz)))
        sl = slice(max(0, i - search_bins), i + search_bins + 1)
        return 20.0 * math.log10(self.comp[sl].max() / self.raw[sl].max())


def compensated_spectrum(beat, mzi, *, fs_hz: float, mzi_delay_s: float, max_delay_s: float,
                         window: str = "hann", edge_s: float | None = None,
                         nfft: int | None = None) -> CompensatedSpectrum:
    """Phase-noise compensated spectrum of one ramp of a LiDAR beat (real, 1-D) using the monitor MZI.

    ``beat`` and ``mzi`` are the same ramp, sample-aligned. Targets up to ``max_delay_s`` round trip
    are compensated (M up to ceil(max_delay / tau_m)); the analysis window starts after that delay
    plus the Hilbert edge so that every delayed MZI sample it needs exists.
    """
    b = check_finite_array("beat", beat, ndim=(1,))
    m_arr = check_finite_array("mzi", mzi, ndim=(1,))
    if b.size != m_arr.size:
        raise ValueError(f"beat and mzi must have the same length, got {b.size} and {m_arr.size}")
    fs_hz = check_positive("fs_hz", fs_hz)
    mzi_delay_s = check_positive("mzi_delay_s", mzi_delay_s)
    max_delay_s = check_positive("max_delay_s", max_delay_s)
    if edge_s is None:
        edge_s = max(20.0 / fs_hz, 1e-6)
    pn = mzi_phase_noise(m_arr, fs_hz=fs_hz, edge_s=edge_s)
    if not pn.f_mzi_hz > 0:
        raise ValueError("mzi: no positive beat frequency found (is the laser chirping?)")
    d = mzi_delay_s * fs_hz
    m_max = int(math.ceil(max_delay_s / mzi_delay_s))
    n_edge = int(math.ceil(edge_s * fs_hz))
    start = n_edge + int(math.ceil(m_max * d))
    stop = b.size - n_edge
    if stop - start < 64:
        raise ValueError(f"ramp of {b.size} samples too short for max_delay_s={max_delay_s!r} and edge_s={edge_s!r}")
    z = hilbert(b - b.mean())[start:stop]
    w = get_window(window, stop - start, fftbins=False)
    nfft = int(nfft or (stop - start))
    freq = np.fft.fftfreq(nfft, d=1.0 / fs_hz)
    pos = (freq >= 0) & (freq < fs_hz / 2)
    freq = freq[pos]
    raw = np.abs(np.fft.fft(z * w, nfft))[pos]
    m_of_bin = np.clip(np.rint(freq / pn.f_mzi_hz), 0, m_max).astype(int)
    comp = np.empty_like(raw)
    for m, s in cumulative_phase_noise(pn.delta_rad, m_max, d):
        sel = m_of_bin == m
        if not sel.any():
            continue
        spec = np.abs(np.fft.fft(z * np.exp(-1j * s[start:stop]) * w, nfft))[pos]
        comp[sel] = spec[sel]
    return CompensatedSpectrum(freq_hz=freq, raw=raw, comp=comp, m_of_bin=m_of_bin, f_mzi_hz=pn.f_mzi_hz,
                               start=start)
