"""ILC update: fit the drive-to-frequency response and turn an error into the next drive (§2.2).

``u_{k+1} = Q[ u_k + beta F^-1{ E_k(f) / H(f) } ]`` (``update="inverse"``) with H(f) fitted each
iteration by :func:`fit_fm_response` (a generic bank of first-order low passes, no laser model), or
``u_k + beta e_k / K`` (``update="scalar"``); Q is a zero-phase FFT low pass over the periodic drive.
:func:`propose_drive` also enforces the peak-drive cap: a step beyond it is retried once at half the
gain with the scalar law and otherwise never sent. Used by :func:`lidard.dsp.linearize.ilc.linearize`.

Pure numpy: no I/O, no clock, no logging.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..spectrum.instfreq import fft_filter

# inverse-response update (see fit_fm_response): a generic first-order basis, log-spaced
_BASIS_TAUS_S = (10e-9, 30e-9, 100e-9, 300e-9, 1e-6, 3e-6, 10e-6, 30e-6, 100e-6, 300e-6, 1e-3, 3e-3)
_BASIS_RIDGE = 1e-2
_BASIS_DECIMATE = 4
_INVERSE_FLOOR = 0.1


def fit_fm_response(drive_v: ArrayLike, ramps_nu: Sequence[tuple[np.ndarray, np.ndarray]], *, fs_drive_hz: float, ramp_s: float, learn: float,
                    floor_hz_per_v: float) -> np.ndarray:
    """Model-free estimate of the FM response H(f) (Hz/V, drive frame) on the drive's rfft grid.

    The measured drive-frame frequency over the learning regions is regressed on the drive passed
    through a fixed, generic bank of first-order low passes (log-spaced 10 ns .. 3 ms, plus the
    direct term) with a free offset per ramp; ridge-regularised least squares. Nothing about the
    laser goes in: only the drive that was sent and what the MZI saw. ``|H|`` is floored at
    ``floor_hz_per_v`` so that dividing by it never blows up where the fit is poor.

    Why: one scalar K is right for the slow part of a DFB's response and 5-10x too large for its fast
    part (the carrier and thermal terms cancel at high frequency), and it ignores the thermal phase
    lag, so fine features learn slowly and a slow tail couples the ramps. Dividing the error by the
    fitted H(f) is the classic inverse-model ILC update.
    """
    u = np.asarray(drive_v, dtype=np.float64)
    n = u.size
    f = np.fft.rfftfreq(n, d=1.0 / fs_drive_hz)
    spec = np.fft.rfft(u)
    resp = [np.ones_like(f, dtype=complex)] + [1.0 / (1.0 + 2j * np.pi * f * tau) for tau in _BASIS_TAUS_S]
    basis = [np.fft.irfft(spec * r, n=n) for r in resp]
    td = np.arange(n) / fs_drive_hz
    rows, ys = [], []
    for r, (t, nu) in enumerate(ramps_nu):
        tr = t - r * ramp_s
        m = (tr >= 0.5 * (1 - learn) * ramp_s) & (tr <= 0.5 * (1 + learn) * ramp_s)
        tm = t[m][::_BASIS_DECIMATE]
        cols = [np.interp(tm, td, b, period=2 * ramp_s) for b in basis]
        cols += [np.full(tm.size, 1.0 if q == r else 0.0) for q in range(len(ramps_nu))]
        rows.append(np.stack(cols, axis=1))
        ys.append(nu[m][::_BASIS_DECIMATE])
    a = np.concatenate(rows)
    y = np.concatenate(ys)
    scale = np.abs(a).max(axis=0)
    scale[scale == 0] = 1.0
    an = a / scale
    gram = an.T @ an
    lam = _BASIS_RIDGE * np.trace(gram) / gram.shape[0]
    g = np.linalg.solve(gram + lam * np.eye(gram.shape[0]), an.T @ y) / scale
    h = sum(gk * rk for gk, rk in zip(g[:len(resp)], resp))
    mag = np.abs(h)
    return np.where(mag < floor_hz_per_v, h / np.maximum(mag, 1e-300) * floor_hz_per_v, h)



@dataclass(frozen=True)
class Proposal:
    """The next drive (None if no drive within the cap could be made), the gain it was made with,
    and why learning must stop (empty while it may go on)."""

    drive_v: np.ndarray | None
    beta: float
    reason: str = ""


@dataclass(frozen=True)
class UpdateLaw:
    """How every learning step of one linearization is made: the law (``update``: "inverse" divides the
    error by the fitted FM response, "scalar" by the tuning slope), the drive's sample rate (Hz) and
    ramp (s), the learning region (fraction of a ramp), the Q filter's cut-off (Hz), and the peak-drive
    cap: ``cap_v``, how it reads in a stop reason (``cap_text``), and the smallest gain a capped step
    may back off to (``min_beta``)."""

    update: str
    fs_drive_hz: float
    ramp_s: float
    learn: float
    q_cutoff_hz: float
    cap_v: float
    min_beta: float
    cap_text: str


def propose_drive(cur_u: np.ndarray, err_drive: np.ndarray, ramps_nu: Sequence[tuple[np.ndarray, np.ndarray]],
                  law: UpdateLaw, *, tuning_hz_per_v: float, beta: float) -> Proposal:
    """One learning step from ``cur_u`` with error ``err_drive`` (Hz, drive grid), low-passed by Q.

    A step whose peak exceeds ``cap_v`` is a broken measurement or fit, never a linearization: the
    gain is halved and the plain scalar step tried once; if that too exceeds the cap (or the gain
    fell below ``min_beta``) no drive is proposed and ``reason`` says why.
    """
    update, fs_drive_hz, ramp_s, learn, q_cutoff_hz = law.update, law.fs_drive_hz, law.ramp_s, law.learn, law.q_cutoff_hz
    cap_v, min_beta, cap_text = law.cap_v, law.min_beta, law.cap_text
    K = tuning_hz_per_v
    if update == "inverse":
        h = fit_fm_response(cur_u, ramps_nu, fs_drive_hz=fs_drive_hz, ramp_s=ramp_s, learn=learn,
                            floor_hz_per_v=_INVERSE_FLOOR * K)
        step = np.fft.irfft(np.fft.rfft(err_drive) / h, n=cur_u.size)
    else:
        step = err_drive / K
    u = fft_filter(cur_u + beta * step, fs_drive_hz, hi_hz=q_cutoff_hz)
    if np.abs(u).max() <= cap_v:
        return Proposal(u, beta)
    beta *= 0.5
    if beta < min_beta:
        return Proposal(None, beta, "beta backed off below min_beta")
    u = fft_filter(cur_u + beta * err_drive / K, fs_drive_hz, hi_hz=q_cutoff_hz)
    if not np.abs(u).max() <= cap_v:
        return Proposal(None, beta, f"update would exceed {cap_text}")
    return Proposal(u, beta)
