"""Monitor-MZI beat -> instantaneous optical frequency (dissertation §2.2, Fig. 2-3 "HT" block).

A monitor Mach-Zehnder interferometer of delay tau_m turns the swept laser into a beat
``cos(psi(t))`` with ``psi(t) = 2 pi int_{t - tau_m}^{t} nu(s) ds + phi(t) - phi(t - tau_m)``.
Its Hilbert phase, unwrapped, is therefore ``2 pi tau_m`` times the optical frequency *averaged over
the last tau_m*, i.e. ``nu(t - tau_m / 2)`` to second order: the estimate is delayed by tau_m / 2 and
this module puts it back on the right time axis.

Three facts the helpers below take care of:

* The Hilbert phase of a *real* beat always increases (the analytic signal keeps the positive
  frequency), so the optical slope's sign is lost. An intensity MZI cannot tell an up-chirp from a
  down-chirp; what *is* known is which way the drive goes. The estimate is therefore returned in the
  **drive frame**: ``nu_d = direction * phase / (2 pi tau_m)`` with ``direction = +1`` on a ramp where
  the drive rises and -1 where it falls, i.e. ``nu_d = sign(K) * nu`` for a laser of tuning sign K.
  A model-free learning law only needs this (d nu_d / d u > 0 whatever the laser does).
* The analytic signal is wrong for a few beat periods at the ends of a segment (Hilbert edge
  transients) and at the turning points, where the beat frequency passes through zero. Segments are
  mirror-padded before the transform and the caller discards an edge margin.
* At low MZI SNR the unwrapped phase can slip by 2 pi. ``count_phase_slips`` detects steps of about
  2 pi against a smooth trend so that a caller can report them instead of learning them.

Pure numpy/scipy: no I/O, no clock, no logging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


def hilbert(x: ArrayLike, axis: int = -1) -> np.ndarray:
    """The analytic signal x + j H{x} of real ``x`` along ``axis`` (Marple's discrete form, the same
    as scipy.signal.hilbert): the FFT with the negative frequencies zeroed, the positive ones doubled,
    DC and (for an even length) Nyquist kept once. numpy's FFT: importing scipy.signal costs about a
    second of every command's start-up."""
    x = np.asarray(x)
    if np.iscomplexobj(x):
        raise ValueError("hilbert: x must be real")
    n = x.shape[axis]
    if n == 0:
        raise ValueError("hilbert: x is empty along its axis")
    h = np.zeros(n)
    h[0] = 1.0
    if n % 2 == 0:
        h[n // 2] = 1.0
        h[1:n // 2] = 2.0
    else:
        h[1:(n + 1) // 2] = 2.0
    shape = [1] * x.ndim
    shape[axis] = n
    return np.fft.ifft(np.fft.fft(x, axis=axis) * h.reshape(shape), axis=axis)


def check_finite_array(name: str, x: ArrayLike, *, ndim: tuple[int, ...] | None = None) -> np.ndarray:
    """float64 copy-free view of ``x``; ValueError naming ``name`` if NaN/inf or wrong rank."""
    a = np.asarray(x, dtype=np.float64)
    if ndim is not None and a.ndim not in ndim:
        raise ValueError(f"{name}: expected an array of rank {' or '.join(map(str, ndim))}, got shape {a.shape}")
    if a.size == 0:
        raise ValueError(f"{name}: empty array")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains NaN or inf")
    return a


def check_positive(name: str, v: float) -> float:
    v = float(v)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be positive and finite, got {v!r}")
    return v


def _smooth_mask(f_abs: np.ndarray, lo_hz: float | None, hi_hz: float | None) -> np.ndarray:
    """Band mask with raised-cosine skirts (one octave wide) so the filter does not ring."""
    m = np.ones_like(f_abs)
    if hi_hz is not None:
        x = np.clip((f_abs - hi_hz) / hi_hz, 0.0, 1.0)        # hi .. 2 hi
        m *= 0.5 * (1.0 + np.cos(np.pi * x))
    if lo_hz is not None and lo_hz > 0:
        x = np.clip((f_abs - lo_hz / 2) / (lo_hz / 2), 0.0, 1.0)  # lo/2 .. lo
        m *= 0.5 * (1.0 - np.cos(np.pi * x))
    return m


def fft_filter(x: ArrayLike, fs_hz: float, *, lo_hz: float | None = None, hi_hz: float | None = None,
               axis: int = -1) -> np.ndarray:
    """Zero-phase band filter by an FFT mask; treats the record as one period (circular)."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[axis]
    spec = np.fft.rfft(x, axis=axis)
    mask = _smooth_mask(np.fft.rfftfreq(n, d=1.0 / fs_hz), lo_hz, hi_hz)
    shape = [1] * x.ndim
    shape[axis] = mask.size
    return np.fft.irfft(spec * mask.reshape(shape), n=n, axis=axis)


def gaussian_lowpass(x: ArrayLike, fs_hz: float, cutoff_hz: float, axis: int = -1) -> np.ndarray:
    """Zero-phase Gaussian low pass (-3 dB at cutoff_hz), circular.

    A Gaussian response has a Gaussian impulse response: no ringing. A brick-wall or raised-cosine
    mask rings at its corner frequencies wherever the signal has a fast feature, and a learning loop
    would faithfully learn that ringing into the drive.
    """
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[axis]
    f = np.fft.rfftfreq(n, d=1.0 / fs_hz)
    mask = np.exp(-0.5 * np.log(2.0) * (f / cutoff_hz) ** 2)
    shape = [1] * x.ndim
    shape[axis] = mask.size
    return np.fft.irfft(np.fft.rfft(x, axis=axis) * mask.reshape(shape), n=n, axis=axis)


def lowpass_padded(x: ArrayLike, fs_hz: float, cutoff_hz: float) -> np.ndarray:
    """Zero-phase Gaussian low pass of a non-periodic 1-D segment.

    Odd mirror padding (continuous value and slope) hides the jump between the segment's ends that a
    circular filter would otherwise smear into both of them.
    """
    x = np.asarray(x, dtype=np.float64)
    pad = min(x.size - 1, max(1, int(math.ceil(2.0 * fs_hz / cutoff_hz))))
    ext = np.concatenate([2 * x[0] - x[pad:0:-1], x, 2 * x[-1] - x[-2:-pad - 2:-1]])
    return gaussian_lowpass(ext, fs_hz, cutoff_hz)[pad:pad + x.size]


def analytic_phase(x: ArrayLike, pad: int) -> tuple[np.ndarray, np.ndarray]:
    """Unwrapped Hilbert phase (rad, increasing for a positive-frequency beat) and envelope of ``x``.

    ``x`` is one segment (not periodic); ``pad`` samples of mirror image are added at both ends so
    the transform's edge transient falls mostly outside the segment.
    """
    x = np.asarray(x, dtype=np.float64)
    pad = int(min(max(pad, 0), x.size - 1))
    ext = np.concatenate([x[pad:0:-1], x, x[-2:-pad - 2:-1]]) if pad else x
    z = hilbert(ext)[pad:pad + x.size]
    return np.unwrap(np.angle(z)), np.abs(z)


def count_phase_slips(phase_rad: ArrayLike, fs_hz: float, trend_hz: float) -> int:
    """Number of ~2 pi steps of an unwrapped phase against its smooth trend (low pass at trend_hz).

    A slip is a step of 2 pi; against a low-passed copy it leaves a residual that swings past
    +-pi/2 (a step filtered by a low pass leaves +-pi around the step). Noise of a healthy beat is
    far below that. Each run of samples beyond the threshold counts as one event.
    """
    ph = np.asarray(phase_rad, dtype=np.float64)
    if ph.size < 8:
        return 0
    r = ph - lowpass_padded(ph, fs_hz, trend_hz)
    out = np.abs(r) > 0.5 * np.pi
    if not out.any():
        return 0
    starts = np.flatnonzero(out[1:] & ~out[:-1]).size + int(out[0])
    # a step yields two lobes (before and after it) close together: one event per lobe pair
    return max(1, (starts + 1) // 2)


@dataclass(frozen=True)
class RampFrequency:
    """Drive-frame optical frequency on one ramp, estimated from the monitor MZI.

    ``t_s``: times (s from the start of the record) *after* the tau_m/2 correction;
    ``nu_hz``: drive-frame frequency (arbitrary constant offset); ``envelope``: |analytic signal|;
    ``valid``: samples away from the segment ends (Hilbert transients) and turning points.
    """

    t_s: np.ndarray
    nu_hz: np.ndarray
    envelope: np.ndarray
    valid: np.ndarray
    phase_slips: int
    direction: int


def ramp_frequency(mzi_ramp: ArrayLike, *, fs_hz: float, mzi_delay_s: float, t0_s: float, direction: int,
                   edge_s: float, trend_hz: float) -> RampFrequency:
    """Drive-frame instantaneous frequency of one ramp of a (band-passed) monitor-MZI beat.

    ``t0_s`` is the time of the segment's first sample; ``direction`` +1 if the drive rises on this
    ramp, -1 if it falls (restores the sign the real beat lost); ``edge_s`` is discarded at both ends.
    """
    if direction not in (1, -1):
        raise ValueError(f"direction must be +1 or -1, got {direction!r}")
    x = np.asarray(mzi_ramp, dtype=np.float64)
    n_edge = int(math.ceil(edge_s * fs_hz))
    phase, env = analytic_phase(x - x.mean(), pad=max(n_edge, 1))
    valid = np.zeros(x.size, dtype=bool)
    valid[n_edge:x.size - n_edge] = True
    slips = count_phase_slips(phase[valid], fs_hz, trend_hz) if valid.sum() > 8 else 0
    # psi / (2 pi tau_m) is nu averaged over [t - tau_m, t], i.e. nu at t - tau_m/2
    t = t0_s + np.arange(x.size) / fs_hz - 0.5 * mzi_delay_s
    nu = direction * phase / (2.0 * np.pi * mzi_delay_s)
    return RampFrequency(t_s=t, nu_hz=nu, envelope=env, valid=valid, phase_slips=slips, direction=direction)


def best_fit_residual(t: ArrayLike, y: ArrayLike) -> np.ndarray:
    """y minus its least-squares straight line in t."""
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    tc = t - t.mean()
    slope = float(np.dot(tc, y - y.mean()) / np.dot(tc, tc))
    return y - y.mean() - slope * tc
