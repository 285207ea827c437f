"""One return's beat frequency from all the records of a pixel: the maximum-likelihood estimate (§2.1, eq. 2-1).

A pixel is L records (segments) of the same beam, one period T apart. Each record holds the return's
tone with its own complex amplitude (speckle, the record's start phase) in white noise. Record l's
likelihood of a frequency f is J_l(f): for a real ramp the least-squares energy of the best real
sinusoid at f (the tone and its negative-frequency image, as the one-record ``newton`` estimator of
:mod:`.estimators`), for an I/Q ramp the periodogram |X_l(f)|^2 of the raw record. The records are
independent, so the pixel's log-likelihood is their sum, and its maximum is the maximum-likelihood
estimate of the pixel's frequency: one estimate from L records, at the L-record Cramer-Rao bound
(var ~ 1/L of one record's) once past threshold, where the mean of L one-record estimates carries each
record's threshold (and its outliers) into the mean.

A moving return: its range, and so its beat, changes by 2 gamma v T / c from one record to the next
(gamma the chirp rate; the Doppler shift is constant). The model is then f_l = f + (l - (L - 1) / 2) s,
with the drift s bounded by the speed band the record was sized for (``max_drift``): f is the beat at
the pixel's middle record, the instant the frame DSP refers its range to
(:meth:`lidard.dsp.frame.FrameDsp.measurement_delay_s`). The centred record index makes f and s
orthogonal (the cross term of their Fisher information sums the centred indices: zero for records of
equal power), so fitting s costs f nothing at the bound, and a common frequency fitted to a drifting
beat would leave a misfit that the model-order test (:mod:`.order`) reads as a second surface.
Whether the drift belongs to the model is itself a model-order question: the likelihood it gains over
a common frequency (:attr:`PixelFit.gain`, from the quadratic model at the fit) is chi-square with one
degree of freedom when the return does not move; the frame DSP keeps it past the model-order test's
level and otherwise takes the common frequency (:func:`lidard.dsp.ranging.ramp.refine_ramp`).

Newton's method in (f, s): the derivatives of the sum are sums of each record's slope and curvature
at its own f_l (the three-point differences of the one-record estimator), weighted by 1, c_l, c_l^2:
no more likelihood evaluations than refining every record by itself. Pure numpy; where numba is
loaded each iteration's per-record slopes are one compiled pass (lidard.dsp.spectrum._kernels.real_slopes).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..spectrum import jit
from ..spectrum.dtft import _DtftNearBin, _terms_for
from .estimators import _real_tone_fit

#: Newton iterations (from the pooled three-bin start, within a few hundredths of a bin past
#: threshold, as the one-record ``newton`` estimator's three)
ITERATIONS = 3
#: the pixel's frequency moves at most this far (bins) from its start
REACH_BINS = 0.5
#: a tone's likelihood near its peak, J(f0 + e) ~ J(f0) (1 - (pi e)^2 / 3) for a record of N samples
#: (the Dirichlet kernel's |D|^2 to second order): its curvature in bins^-2 over J(f0), the step's
#: scale where the likelihood is not concave
PEAK_CURVATURE = 2.0 * np.pi ** 2 / 3.0
#: finite-difference step of the real-tone likelihood's derivatives (bins, as the one-record estimator's)
_H = 1e-3


class PixelFit(NamedTuple):
    """One return's fit to a pixel's records (P,) each, bins of the N-point grid: ``freq`` the beat at
    the middle record and ``drift`` its change a record; ``common`` the beat with no drift (the
    maximum of the likelihood along s = 0, from the quadratic model at the fit); ``gain`` the
    likelihood's energy gained by the drift over ``common`` (J's units: the records' squared volts)."""

    freq: np.ndarray
    drift: np.ndarray
    common: np.ndarray
    gain: np.ndarray


def record_offsets(l_n: int) -> np.ndarray:
    """The centred record indices (L,): record l's beat is f + offsets[l] x drift."""
    return np.arange(l_n) - 0.5 * (l_n - 1)


def refine_pixel_tone(x: np.ndarray, start: np.ndarray, *, max_drift: float = 0.0, iterations: int = ITERATIONS,
                      rows: np.ndarray | None = None) -> PixelFit:
    """Each pixel's beat at its middle record and its drift per record (:class:`PixelFit`). ``x`` (P, L, N) the pixels' records (real, or complex I/Q: ``start`` signed),
    ``start`` (P,) bins; ``max_drift`` (bins per record) the largest drift a target inside the speed
    band gives (0, or one record: a common frequency). ``rows`` (P,): the pixels are these rows of ``x``
    (read in place: gathering a frame's records cost as much as the fit's moments)."""
    x = np.asarray(x)
    _, l_n, n = x.shape
    start = np.asarray(start, dtype=np.float64)
    p_n = start.size
    flat = None if rows is None else (np.asarray(rows, dtype=np.int64)[:, None] * l_n + np.arange(l_n)).ravel()
    if p_n == 0:
        return PixelFit(start.copy(), np.zeros(0), start.copy(), np.zeros(0))
    c = record_offsets(l_n)
    max_drift = float(max_drift) if l_n >= 2 else 0.0      # one record: no drift to see
    centre = np.rint(start)
    span = REACH_BINS + float(max_drift) * float(np.abs(c).max())
    ev = _DtftNearBin(x.reshape(-1, n), flat, np.repeat(centre, l_n), _terms_for(span + 0.51 + _H))
    real = x.dtype.kind != "c"
    d0 = start - centre
    d = d0.copy()
    s = np.zeros(p_n)
    h_ff = h_fs = h_ss = np.zeros(p_n)
    for _ in range(iterations):
        j, slope, curv = (a.reshape(p_n, l_n) for a in _record_slopes(ev, (d[:, None] + c * s[:, None]).ravel(),
                                                                      real, n))
        g_f, h_ff = slope.sum(axis=1), curv.sum(axis=1)
        if max_drift > 0:
            g_s, h_fs, h_ss = slope @ c, curv @ c, curv @ (c * c)
            det = h_ff * h_ss - h_fs * h_fs
            # not concave in (f, s) (a record beyond its lobe's top, a drift not yet fitted): the
            # curvature each record's tone has at its peak instead, -PEAK_CURVATURE J_l per bin^2
            flank = ~((h_ff < 0) & (det > 0))
            h_ff = np.where(flank, -PEAK_CURVATURE * j.sum(axis=1), h_ff)
            h_fs = np.where(flank, -PEAK_CURVATURE * (j @ c), h_fs)
            h_ss = np.where(flank, -PEAK_CURVATURE * (j @ (c * c)), h_ss)
            det = h_ff * h_ss - h_fs * h_fs
            step_f = _ratio(-h_ss * g_f + h_fs * g_s, det)
            step_s = _ratio(h_fs * g_f - h_ff * g_s, det)
        else:
            h_ff = np.where(h_ff < 0, h_ff, -PEAK_CURVATURE * j.sum(axis=1))
            step_f, step_s = _ratio(-g_f, h_ff), np.zeros(p_n)
        d = np.clip(d + np.clip(step_f, -0.25, 0.25), d0 - REACH_BINS, d0 + REACH_BINS)
        s = np.clip(s + step_s, -max_drift, max_drift)
    if max_drift <= 0:
        return PixelFit(centre + d, s, centre + d, np.zeros(p_n))
    # the quadratic model at the fit: along s = 0 the likelihood peaks h_fs s / h_ff further, s^2 / 2
    # (h_fs^2 / h_ff - h_ss) lower (the Schur complement of the last Hessian, negative definite there)
    common = centre + d + _ratio(h_fs * s, h_ff)
    gain = np.maximum(0.5 * s * s * (_ratio(h_fs * h_fs, h_ff) - h_ss), 0.0)
    return PixelFit(centre + d, s, common, gain)


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    out = np.zeros(np.broadcast(num, den).shape)
    np.divide(num, den, out=out, where=den != 0)
    return out


def _record_slopes(ev: _DtftNearBin, d: np.ndarray, real: bool,
                   n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each record's likelihood, its slope and curvature (m,) in bins at ``d`` from its moments' centre."""
    if not real:    # the periodogram |X|^2 = |G|^2: exact derivatives
        g, g1, g2 = ev.eval(d, derivs=2)
        return (np.abs(g) ** 2, 2.0 * np.real(np.conj(g) * g1),
                2.0 * (np.abs(g1) ** 2 + np.real(np.conj(g) * g2)))
    kern = jit.kernels(0)
    if kern is None:
        jm, j0, jp = _real_tone_fit(ev, d, np.array([-_H, 0.0, _H]))
        return j0, (jp - jm) / (2.0 * _H), (jp - 2.0 * j0 + jm) / (_H * _H)
    o = np.array([-_H, 0.0, _H])
    gr, gi = ev._terms()
    turn = np.empty((6, 3))
    for row, by in enumerate((np.pi * o * (n - 1) / n, 2.0 * np.pi * o / n, 2.0 * np.pi * o / n * (n - 1))):
        turn[2 * row], turn[2 * row + 1] = np.cos(by), np.sin(by)
    phi = np.pi * d * (n - 1) / n
    w = 2.0 * np.pi * (ev.f0 + d) / n
    w1 = w * (n - 1)
    energy, slope, curv = np.empty(d.size), np.empty(d.size), np.empty(d.size)
    kern.real_slopes(np.ascontiguousarray(gr), np.ascontiguousarray(gi), np.ascontiguousarray(d), o, np.cos(phi),
                     np.sin(phi), np.cos(w), np.sin(w), np.cos(w1), np.sin(w1), turn, n, 1e-6 * n * n, 2.0 * _H,
                     _H * _H, energy, slope, curv)
    return energy, slope, curv
