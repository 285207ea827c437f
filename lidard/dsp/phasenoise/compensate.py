"""Laser phase-noise compensation from the monitor MZI (dissertation §2.3, Fig. 2-6, Fig. 2-7).

The monitor MZI (delay tau_m) sees the laser phase difference ``Delta phi_m(t) = phi(t) - phi(t - tau_m)``
on top of its deterministic chirp phase. A target at round trip ``tau = M tau_m`` sees
``phi(t) - phi(t - M tau_m) = sum_{m<M} Delta phi_m(t - m tau_m)`` -- exactly, whatever the chirp. So:

1. The monitor beat is mixed down by its beat frequency ``gamma tau_m`` (given as the known chirp
   rate, or measured) and low-passed as a complex phasor; its angle is ``delta(t)`` = phase noise +
   whatever nonlinearity the chirp still has (see :func:`mzi_phase_noise` for why not a Hilbert
   phase). Only the deterministic line is removed: a smooth fit would also remove the slow part of
   the phase noise, which the sum over M multiplies by M. Residual chirp nonlinearity is compensated
   too (it adds up over M exactly like the noise).
2. The analytic LiDAR beat is multiplied by ``exp(-j sum_{m<M} delta(t - m tau_m))`` (no effect on the
   Doppler shift, so velocity survives, §2.3).
3. Every range uses its nearest M: the spectrum is computed once per M and the bins whose beat
   frequency is nearest ``M f_mzi`` (``f_mzi`` = the MZI beat frequency, measured) are stitched.

The sign of the chirp does not matter: on a ramp where the optical frequency falls, both measured
phases (MZI and LiDAR, positive beat frequency) are the negatives of the optical ones, consistently.

Pure numpy/scipy: no I/O, no clock, no logging.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..spectrum.instfreq import check_finite_array, check_positive, hilbert
from .reconstruct import delayed, quadrature_delta, reconstruct_phase, whole_delay_samples
from ..spectrum.window import get_window



@dataclass(frozen=True)
class MziPhaseNoise:
    delta_rad: np.ndarray       # phase-noise (+ nonlinearity) estimate per sample of the ramp
    f_mzi_hz: float             # slope of the best-fit line / 2 pi: the MZI beat frequency
    valid: np.ndarray           # samples away from the Hilbert edge transients


def demodulated_phase(x: np.ndarray, *, fs_hz: float, beat_hz: float, bandwidth_hz: float,
                      valid: np.ndarray) -> np.ndarray:
    """Delta phi_m of zero-mean MZI ramps (last axis; batched over leading ones): mix down by
    ``beat_hz``, Gaussian low-pass (-3 dB at ``bandwidth_hz``) as a complex signal, angle about its
    circular mean over ``valid``, unwrapped; zero outside ``valid``. See :func:`mzi_phase_noise`."""
    n = x.shape[-1]
    k = np.arange(n, dtype=np.float64)
    f = np.fft.fftfreq(n, d=1.0 / fs_hz)
    z = np.fft.ifft(np.fft.fft(x * np.exp(-2j * np.pi * beat_hz / fs_hz * k), axis=-1)
                    * np.exp(-0.5 * np.log(2.0) * (f / bandwidth_hz) ** 2), axis=-1)
    # a constant phase is harmless (it multiplies the compensated beat by a unit phasor); take the
    # circular mean so that delta is centred on 0 for the zero-linewidth case
    zv = z[..., valid]
    c = np.angle(np.sum(zv / np.maximum(np.abs(zv), 1e-300), axis=-1, keepdims=True))
    delta = np.unwrap(np.angle(z * np.exp(-1j * c)), axis=-1)
    delta[..., ~valid] = 0.0
    return delta


def mzi_phase_noise(mzi: ArrayLike, *, fs_hz: float, edge_s: float, bandwidth_hz: float | None = None,
                    beat_hz: float | None = None) -> MziPhaseNoise:
    """Estimate Delta phi_m(t) from one ramp of the monitor-MZI beat (1-D, one ramp).

    Complex demodulation, not a Hilbert phase: the beat is mixed down by its own (measured) mean
    frequency and low-passed (Gaussian, -3 dB at ``bandwidth_hz``, default half the beat frequency)
    *as a complex signal* before its angle is taken. With a broad linewidth the phase deviation of a
    long MZI is of order a radian and reaches far above the beat frequency; the Hilbert phase of a
    band-passed real beat then mixes that wide-band part non-linearly into the band (Bedrosian fails)
    and the errors no longer cancel in the sum over M. Averaging exp(j theta) instead keeps the
    in-band phase (what is lost is the out-of-band part of phi(t) - phi(t - tau_m), which telescopes
    in the sum to phi(t) - phi(t - M tau_m) and so stays bounded whatever M) and a fade of the
    averaged phasor costs a few samples, not a 2 pi slip that tilts a fitted line: the mean beat
    frequency comes from lag products of the phasor, which slips cannot bias.

    ``beat_hz``: the known MZI beat ``gamma tau_m`` (chirp rate times delay, e.g. after ILC
    linearization to a known slope). Prefer it: a frequency measured from the MZI includes the
    realised mean of the laser's frequency noise over the ramp, which belongs to Delta phi_m, and
    removing it would move every compensated peak by M times that mean.
    """
    x = check_finite_array("mzi", mzi, ndim=(1,))
    fs_hz = check_positive("fs_hz", fs_hz)
    n_edge = int(math.ceil(edge_s * fs_hz))
    if 2 * n_edge + 16 > x.size:
        raise ValueError(f"mzi: {x.size} samples are too few for edge_s={edge_s!r} at fs_hz={fs_hz!r}")
    x = x - x.mean()
    n = x.size
    nfft = 8 * n
    if beat_hz is None:
        spec = np.abs(np.fft.rfft(x * np.hanning(n), nfft))
        f_mzi = float(np.argmax(spec[8:]) + 8) * fs_hz / nfft
    else:
        f_mzi = check_positive("beat_hz", beat_hz)
    if bandwidth_hz is None:
        bandwidth_hz = 0.5 * f_mzi
    bandwidth_hz = check_positive("bandwidth_hz", bandwidth_hz)
    k = np.arange(n, dtype=np.float64)
    valid = np.zeros(n, dtype=bool)
    valid[n_edge:n - n_edge] = True
    z = None
    # demodulate, refine the mean frequency from lag products, demodulate again: a ladder of lags,
    # each 4x the last, so that every refinement is well inside the next one's alias-free range
    # without a known beat: short lags only (longer ones alias once the MZI decorrelates, tau_m ~ tau_c)
    lags = () if beat_hz is not None else (16, 64)
    for lag in lags:
        y = x * np.exp(-2j * np.pi * f_mzi / fs_hz * k)
        f = np.fft.fftfreq(n, d=1.0 / fs_hz)
        z = np.fft.ifft(np.fft.fft(y) * np.exp(-0.5 * np.log(2.0) * (f / bandwidth_hz) ** 2))
        zv = z[valid]
        if zv.size <= 2 * lag:
            break
        f_mzi += float(np.angle(np.sum(zv[lag:] * np.conj(zv[:-lag])))) * fs_hz / (2 * np.pi * lag)
    delta = demodulated_phase(x, fs_hz=fs_hz, beat_hz=f_mzi, bandwidth_hz=bandwidth_hz, valid=valid)
    return MziPhaseNoise(delta_rad=delta, f_mzi_hz=f_mzi, valid=valid)


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


def cumulative_phase_noise(delta_rad: ArrayLike, m_max: int,
                           delay_samples: float) -> Iterator[tuple[int, np.ndarray]]:
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


def compensated_spectrum(beat: ArrayLike, mzi: ArrayLike, *, fs_hz: float, mzi_delay_s: float, max_delay_s: float,
                         window: str = "hann", edge_s: float | None = None,
                         nfft: int | None = None, bandwidth_hz: float | None = None,
                         chirp_rate_hz_per_s: float | None = None, mzi_q: ArrayLike | None = None,
                         tau_step_s: float | None = None) -> CompensatedSpectrum:
    """Phase-noise compensated spectrum of one ramp of a LiDAR beat (real, 1-D) using the monitor MZI.

    ``mzi_q``: the quadrature output of the same MZI (sin where ``mzi`` is cos): the laser phase is then
    rebuilt sample by sample (:mod:`lidard.dsp.phasenoise.reconstruct`) and every bin is compensated at its own round
    trip, rounded to ``tau_step_s`` (default tau_m / 16); ``m_of_bin`` then counts steps, not tau_m.
    Needs ``chirp_rate_hz_per_s``. Without ``mzi_q``: the nearest multiple M of tau_m (exact only there).

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
    mzi_beat_hz = None if chirp_rate_hz_per_s is None else check_positive("chirp_rate_hz_per_s", chirp_rate_hz_per_s) * mzi_delay_s
    pn = mzi_phase_noise(m_arr, fs_hz=fs_hz, edge_s=edge_s, bandwidth_hz=bandwidth_hz, beat_hz=mzi_beat_hz)
    if not pn.f_mzi_hz > 0:
        raise ValueError("mzi: no positive beat frequency found (is the laser chirping?)")
    d = mzi_delay_s * fs_hz
    m_max = int(math.ceil(max_delay_s / mzi_delay_s))
    n_edge = int(math.ceil(edge_s * fs_hz))
    start = n_edge + int(math.ceil(m_max * d))
    stop = b.size - n_edge
    if stop - start < 64:
        raise ValueError(f"ramp of {b.size} samples too short for max_delay_s={max_delay_s!r} and edge_s={edge_s!r}")
    span = _Span(fs_hz=fs_hz, window=window, start=start, stop=stop, nfft=nfft, n_edge=n_edge)
    if mzi_q is not None:
        return _reconstructed_spectrum(b, m_arr, mzi_q, span, mzi_delay_s=mzi_delay_s, max_delay_s=max_delay_s,
                                       chirp_rate_hz_per_s=chirp_rate_hz_per_s, tau_step_s=tau_step_s)
    z, w, nfft, pos, freq, raw = _analytic_spectrum(b, span)
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


@dataclass(frozen=True)
class _Span:
    """The analysis span of one ramp: samples [start, stop) at ``fs_hz`` under ``window``, an
    ``nfft``-point FFT (None: the span's length), ``n_edge`` Hilbert-edge samples at each end."""

    fs_hz: float
    window: str
    start: int
    stop: int
    nfft: int | None
    n_edge: int


def _analytic_spectrum(b: np.ndarray,
                       span: _Span) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray, np.ndarray]:
    """The beat's analytic signal over [start, stop), its window, and its uncompensated magnitude
    spectrum on the positive frequencies (both compensations start from it)."""
    window, start, stop, nfft, fs_hz = span.window, span.start, span.stop, span.nfft, span.fs_hz
    z = hilbert(b - b.mean())[start:stop]
    w = get_window(window, stop - start, symmetric=True)
    nfft = int(nfft or (stop - start))
    freq = np.fft.fftfreq(nfft, d=1.0 / fs_hz)
    pos = (freq >= 0) & (freq < fs_hz / 2)
    raw = np.abs(np.fft.fft(z * w, nfft))[pos]
    return z, w, nfft, pos, freq[pos], raw


def _reconstructed_spectrum(b: np.ndarray, mzi_i: np.ndarray, mzi_q: ArrayLike, span: _Span, *, mzi_delay_s: float,
                            max_delay_s: float, chirp_rate_hz_per_s: float | None,
                            tau_step_s: float | None) -> CompensatedSpectrum:
    """compensated_spectrum with a quadrature monitor: phi(t) rebuilt, every bin at its own round trip."""
    fs_hz, start, stop, n_edge = span.fs_hz, span.start, span.stop, span.n_edge
    if chirp_rate_hz_per_s is None:
        raise ValueError("mzi_q needs chirp_rate_hz_per_s (the fringe is demodulated at gamma tau_m)")
    q = check_finite_array("mzi_q", mzi_q, ndim=(1,))
    if q.size != b.size:
        raise ValueError(f"mzi_q must have the beat's length {b.size}, got {q.size}")
    step = check_positive("tau_step_s", tau_step_s if tau_step_s is not None else mzi_delay_s / 16)
    gamma = float(chirp_rate_hz_per_s)
    d_samples = whole_delay_samples(mzi_delay_s, fs_hz)
    delta = quadrature_delta(mzi_i, q, fs_hz=fs_hz, beat_hz=gamma * mzi_delay_s)
    valid = np.zeros(b.size, dtype=bool)
    valid[n_edge:b.size - n_edge] = True
    phi, _ = reconstruct_phase(delta, valid, d_samples)
    z, w, nfft, pos, freq, raw = _analytic_spectrum(b, span)
    g_max = int(math.ceil(max_delay_s / step))
    g_of_bin = np.clip(np.rint(freq / (gamma * step)), 0, g_max).astype(int)
    comp = np.empty_like(raw)
    for g in np.unique(g_of_bin):
        sel = g_of_bin == g
        e = phi[start:stop] - delayed(phi, g * step * fs_hz)[start:stop]
        comp[sel] = np.abs(np.fft.fft(z * np.exp(-1j * e) * w, nfft))[pos][sel]
    return CompensatedSpectrum(freq_hz=freq, raw=raw, comp=comp, m_of_bin=g_of_bin, f_mzi_hz=gamma * mzi_delay_s,
                               start=start)
