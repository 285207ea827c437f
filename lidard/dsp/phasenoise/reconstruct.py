"""Laser phase phi(t) reconstructed from the monitor MZI, for compensation at ANY range (§2.3).

The monitor MZI (delay tau_m = D samples) gives ``delta(t) = phi(t) - phi(t - tau_m)``. Summing D-spaced
copies (:mod:`lidard.dsp.phasenoise.compensate`) compensates a target only at round trips ``M tau_m``; between two
multiples the residual ``phi(t - M tau_m) - phi(t - tau)`` stays (5.7 dB mean loss at 200 m for
tau_c = 0.1 us). Here phi itself is rebuilt on the sample grid, so that any round trip tau is
compensated by ``phi(t) - phi(t - tau)`` (one delayed copy, linear interpolation between samples):

* the recursion ``phi[k] = delta[k] + phi[k - D]`` fixes phi up to a D-periodic function p (the
  unknown phase over the period before the record: the MZI is blind at the comb zeros k / tau_m);
* p is the maximum-likelihood one for a Wiener phase (white frequency noise, the laser model of
  eqs. 2-8..2-10): it minimises the sum of squared phase increments, i.e. each of the D increments of
  p is minus the mean over all periods of the corresponding increment, under the constraint that the
  increments of p sum to 0 over a period. Its error falls as 1 / (number of periods in the ramp);
* the recursion runs on the *wrapped increments* of delta, so a 2 pi slip of an unwrapped phase
  does not repeat into every later period.

The reconstruction needs delta sample by sample, i.e. the MZI's phase without a low-pass filter. A
single photodiode (real fringe) only gives it after a complex low-pass around the fringe frequency
gamma tau_m, which loses the phase noise above about half of it and fades when tau_m exceeds the
coherence time: measured, that leaves ~2 dB mean loss with outliers above 10 dB at tau_c = 0.1 us
(benchmarks/phase_noise.py, method "real"). A quadrature monitor (the same MZI read through a
90-degree hybrid or a 3x3 coupler: a second digitizer channel ``mzi_q`` with sin where ``mzi`` has cos)
gives delta per sample: :func:`quadrature_delta`.

Pure numpy: no I/O, no clock, no logging. Batched over leading axes, ramps on the last.
"""

from __future__ import annotations

import math

import numpy as np

from ..spectrum.window import DspInputError


def quadrature_delta(mzi_i: np.ndarray, mzi_q: np.ndarray, *, fs_hz: float, beat_hz: float) -> np.ndarray:
    """delta(t) (rad, unwrapped, last axis) of a quadrature monitor: angle of (I + jQ) mixed down by the
    nominal fringe frequency ``beat_hz`` = gamma tau_m (the known chirp rate, see compensate for why not a
    measured one). No filter: every sample is one phase measurement."""
    i = np.asarray(mzi_i, dtype=np.float64)
    q = np.asarray(mzi_q, dtype=np.float64)
    if i.shape != q.shape:
        raise DspInputError(f"mzi and mzi_q must have the same shape, got {i.shape} and {q.shape}")
    if not (np.all(np.isfinite(i)) and np.all(np.isfinite(q))):
        raise DspInputError("mzi/mzi_q: contains NaN or inf")
    k = np.arange(i.shape[-1], dtype=np.float64)
    # the offsets (photodiode DC, ADC offset) would bias the angle: the fringe averages out over a ramp
    z = (i - i.mean(axis=-1, keepdims=True)) + 1j * (q - q.mean(axis=-1, keepdims=True))
    # On a falling ramp the fringe turns backwards (frequency -beat_hz) and the laser phase enters the
    # real beat with the opposite sign, which the beat's analytic signal (always turning forwards)
    # absorbs by conjugation: read such a ramp as I - jQ so that delta has the beat's sign convention.
    backwards = np.sum(np.angle(z[..., 1:] * np.conj(z[..., :-1])), axis=-1, keepdims=True) < 0
    z = np.where(backwards, np.conj(z), z)
    return np.unwrap(np.angle(z * np.exp(-2j * np.pi * beat_hz / fs_hz * k)), axis=-1)


def reconstruct_phase(delta: np.ndarray, valid: np.ndarray, delay_samples: int) -> tuple[np.ndarray, int]:
    """(phi, first): phi (rad, same shape as ``delta``) up to a constant per ramp, defined from sample
    ``first`` = (first valid sample) - D to the last valid sample; zero elsewhere.

    ``delta``: phi(k) - phi(k - D) (any constant offset, any 2 pi slips) on the samples where ``valid``
    (a contiguous run on the last axis); ``delay_samples``: D, the monitor delay in whole samples.
    """
    d = np.asarray(delta, dtype=np.float64)
    v = np.asarray(valid, dtype=bool)
    D = int(delay_samples)
    idx = np.flatnonzero(v)
    if v.shape != d.shape[-1:] or idx.size == 0 or idx[-1] - idx[0] + 1 != idx.size:
        raise DspInputError(f"valid must be one contiguous run over the last axis of delta {d.shape}")
    k0, k1 = int(idx[0]), int(idx[-1]) + 1
    if D < 1 or k0 < D or k1 - k0 < 2 * D + 1:
        raise DspInputError(f"reconstruct_phase: delay of {D} samples needs >= {D} samples before and "
                            f">= {2 * D + 1} valid samples, got valid [{k0}, {k1})")
    dv = d[..., k0:k1]
    inc = np.angle(np.exp(1j * np.diff(dv, axis=-1)))          # wrapped: slips do not propagate
    n_inc = inc.shape[-1]
    n_per = -(-n_inc // D)
    pad = np.zeros(d.shape[:-1] + (n_per * D,))
    pad[..., :n_inc] = inc
    # increments of phi = increments of delta + those one period earlier (p's for the first period)
    g = np.cumsum(pad.reshape(d.shape[:-1] + (n_per, D)), axis=-2).reshape(pad.shape)[..., :n_inc]
    j = np.arange(n_inc) % D
    cnt = np.bincount(j, minlength=D).astype(np.float64)
    gp = np.zeros_like(pad)
    gp[..., :n_inc] = g
    mean_g = gp.reshape(d.shape[:-1] + (n_per, D)).sum(axis=-2) / cnt      # (..., D)
    lam = mean_g.sum(axis=-1, keepdims=True) / np.sum(1.0 / cnt)
    q = -mean_g + lam / cnt                                      # ML increments of p, sum 0
    phi_v = np.concatenate([np.zeros(d.shape[:-1] + (1,)), np.cumsum(g + q[..., j], axis=-1)], axis=-1)
    out = np.zeros_like(d)
    out[..., k0:k1] = phi_v
    # the period before: phi(k - D) = phi(k) - delta(k) (delta's own constant is a common offset)
    out[..., k0 - D:k0] = phi_v[..., :D] - (dv[..., :D] - dv[..., :1])
    return out, k0 - D


def whole_delay_samples(mzi_delay_s: float, fs_hz: float) -> int:
    """The monitor delay in samples, which the reconstruction needs whole (its recursion steps by it):
    a fraction of a sample would add a random walk of 2 pi linewidth (fraction / fs) per period.
    DspInputError naming the rate that would fit when tau_m fs is not within 0.02 of an integer."""
    d = float(mzi_delay_s) * float(fs_hz)
    if not (math.isfinite(d) and d >= 1) or abs(d - round(d)) > 0.02:
        near = max(1, round(d)) if math.isfinite(d) else 1
        raise DspInputError(f"mzi_delay_s * fs_hz = {d:.3f} samples: the quadrature-monitor reconstruction needs a "
                            f"whole number; sample at a multiple of 1 / mzi_delay_s, e.g. fs_hz = {near / mzi_delay_s:.6g}")
    return int(round(d))


def delayed(x: np.ndarray, shift_samples: float) -> np.ndarray:
    """x(k - shift) along the last axis (linear interpolation), zero where k - shift < 0."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[-1]
    i = int(np.floor(shift_samples))
    frac = float(shift_samples) - i
    out = np.zeros_like(x)
    if i < n:
        out[..., i:] = x[..., :n - i]
    if frac > 1e-9:
        nxt = np.zeros_like(x)
        if i + 1 < n:
            nxt[..., i + 1:] = x[..., :n - i - 1]
        out = (1.0 - frac) * out + frac * nxt
    return out
