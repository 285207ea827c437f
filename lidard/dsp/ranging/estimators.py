"""Sub-bin beat-frequency estimators (dissertation §2.1, eqs. 2-1 and 2-6: range is linear in f_b).

A range FFT locates a target to one bin (c / (2 gamma T), eq. 2-3); these estimators refine the
peak to a fraction of a bin.  All are selected by name from one registry (:data:`ESTIMATORS`) and
run batched over ramps (no Python loop over ramps; loops run over a handful of iterations or
polynomial terms only).

Methods (all return the refined frequency in bins of the spectrum grid that ``peak_bins`` index,
i.e. ``freq_hz = result * fs / (n_samples * zero_pad)``):

``argmax``      the peak bin itself.
``parabolic``   parabola through the log-magnitudes of the three bins around the peak.
``jacobsen``    Candan's bias-corrected form of Jacobsen's estimator, r = Re((X[-1]-X[1]) /
                (2X[0]-X[-1]-X[1])), mapped to the offset through the exact noise-free curve r(delta)
                of the chosen window, length and zero-padding (computed once and cached).  For the
                rectangular window this reproduces Candan's tan(pi/N)/(pi/N) correction; for Hann
                it is r = delta/2 asymptotically; Blackman-Harris has no closed form, hence the table.
``quinn2``      Quinn's second estimator (1997) on the unwindowed DFT of the raw samples.
``aboutanios``  Aboutanios-Mulgrew (2005) interpolation on the DTFT at +-1/2 bin of the current
                estimate, two iterations, on the raw (unwindowed) samples.
``newton``      Newton iterations on the likelihood of a single tone in white noise, started from
                ``jacobsen`` on the windowed spectrum: for I/Q ramps the periodogram |X(f)|^2 of the
                raw samples; for real ramps the least-squares energy of the best real sinusoid
                (which also models the tone's negative-frequency image).  DEFAULT: it reaches the Rife-Boorstyn bound (crlb.py) at
                every sub-bin offset once the post-FFT SNR is past threshold.

The DTFT machinery they share (window DTFT and Jacobsen tables, X(f) near a bin through moments) is
:mod:`lidard.dsp.spectrum.dtft`.

Known limits: ``quinn2`` and ``aboutanios`` treat a real ramp's negative-frequency image as
interference, so close to DC or Nyquist they carry a bias of order 1/(2 pi k) bins (``newton``
models the image); a second target inside the main lobe biases every method.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, get_args

import numpy as np

from lidard.dsp.spectrum import jit
from lidard.dsp.spectrum.dtft import (  # noqa: F401  (_small_gemm: tests reach in)
    _DtftNearBin, _jacobsen_ratio, _jacobsen_table, _safe_ratio, _small_gemm, _terms_for,
)
from lidard.dsp.spectrum.windowdtft import _dirichlet  # noqa: F401  (tests reach in)
from lidard.dsp.spectrum.rangefft import check_samples, gather_bins, windowed_fft
from lidard.dsp.spectrum.window import DspInputError, WindowName, check_window_name, get_window

EstimatorName = Literal["argmax", "parabolic", "jacobsen", "quinn2", "aboutanios", "newton"]
ESTIMATOR_NAMES: tuple[str, ...] = get_args(EstimatorName)
DEFAULT_METHOD: EstimatorName = "newton"


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------
class _Batch:
    """Flattened view of a call: rows of samples, one peak per (row, k) and the spectrum grid."""

    def __init__(self, x: np.ndarray, peak_bins: np.ndarray, window: str, zero_pad: int, spectrum,
                 rows: np.ndarray | None = None):
        self.x = x.reshape(-1, x.shape[-1])
        self.n = x.shape[-1]
        self.zero_pad = zero_pad
        self.n_fft = self.n * zero_pad
        self.iq = x.dtype.kind == "c"
        self.window = window
        # rows: peak row i sits on ramp x[rows[i]] (and spectrum[rows[i]]): the refined ramps are
        # read in place instead of being gathered first (:func:`estimate_rows`)
        self.rows = rows
        n_rows = self.x.shape[0] if rows is None else rows.size
        self.pb = peak_bins.reshape(n_rows, -1).astype(np.int64)
        self._spectrum = None if spectrum is None else spectrum.reshape(self.x.shape[0], -1)

    @property
    def spectrum(self) -> np.ndarray:
        """Windowed spectrum in RangeFFT layout (computed on demand if not supplied)."""
        if self._spectrum is None:
            self._spectrum = windowed_fft(self.x, get_window(self.window, self.n), self.n_fft,
                                          "shifted" if self.iq else "real")
        return self._spectrum

    def three_bins(self, spec: np.ndarray, centre: np.ndarray, n_fft: int):
        m, k = centre.shape
        idx = (centre[:, :, None] + np.array([-1, 0, 1])).reshape(m, 3 * k)
        v = gather_bins(spec, idx, n_fft, self.iq, self.rows if spec is self._spectrum else None).reshape(m, k, 3)
        return v[..., 0], v[..., 1], v[..., 2]


# ---------------------------------------------------------------------------------------------
# estimators: each takes a _Batch and returns fractional bins (rows, K) in the padded grid
# ---------------------------------------------------------------------------------------------
def _est_argmax(b: _Batch) -> np.ndarray:
    return b.pb.astype(np.float64)


def _est_parabolic(b: _Batch) -> np.ndarray:
    xm, x0, xp = b.three_bins(b.spectrum, b.pb, b.n_fft)
    tiny = np.finfo(np.float64).tiny
    lm, l0, lp = (np.log(np.abs(v) + tiny) for v in (xm, x0, xp))
    den = lm - 2.0 * l0 + lp
    d = np.where(den < 0, _safe_ratio(0.5 * (lm - lp), den), 0.0)
    return b.pb + np.clip(d, -1.0, 1.0)


def _jacobsen_offset(b: _Batch) -> np.ndarray:
    xm, x0, xp = b.three_bins(b.spectrum, b.pb, b.n_fft)
    r = _jacobsen_ratio(xm, x0, xp)
    r_tab, d_tab = _jacobsen_table(b.window, b.n, b.zero_pad)
    return np.interp(r, r_tab, d_tab)


def _est_jacobsen(b: _Batch) -> np.ndarray:
    return b.pb + _jacobsen_offset(b)


def _quinn_tau(x: np.ndarray) -> np.ndarray:
    r = np.sqrt(2.0 / 3.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = 0.25 * np.log(3 * x**2 + 6 * x + 1) - np.sqrt(6) / 24 * np.log((x + 1 - r) / (x + 1 + r))
    return np.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0)


def _est_quinn2(b: _Batch) -> np.ndarray:
    k = np.rint(b.pb / b.zero_pad).astype(np.int64)
    spec = np.fft.fftshift(np.fft.fft(b.x, axis=-1), axes=-1) if b.iq else np.fft.rfft(b.x, axis=-1)
    xm, x0, xp = b.three_bins(spec, k, b.n)
    p0 = np.abs(x0) ** 2
    ap = _safe_ratio(np.real(xp * np.conj(x0)), p0)
    am = _safe_ratio(np.real(xm * np.conj(x0)), p0)
    dp = _safe_ratio(-ap, 1.0 - ap)
    dm = _safe_ratio(am, 1.0 - am)
    d = (dp + dm) / 2.0 + _quinn_tau(dp**2) - _quinn_tau(dm**2)
    return (k + np.clip(d, -1.0, 1.0)) * b.zero_pad


def _near(b: _Batch, f0_bins: np.ndarray, max_abs_delta: float) -> _DtftNearBin:
    """Moment evaluator around original-grid frequencies f0 (one per (ramp, peak))."""
    k = b.pb.shape[1]
    rows: np.ndarray | None
    if b.rows is not None:
        rows = b.rows if k == 1 else np.repeat(b.rows, k)
    else:
        rows = None if k == 1 else np.repeat(np.arange(b.x.shape[0]), k)
    return _DtftNearBin(b.x, rows, np.ascontiguousarray(f0_bins, dtype=np.float64).ravel(), _terms_for(max_abs_delta))


def _est_aboutanios(b: _Batch) -> np.ndarray:
    f0 = b.pb / b.zero_pad
    ev = _near(b, f0, 1.25)
    d = np.zeros(ev.f0.shape)
    for _ in range(2):
        sp = ev.dtft(d + 0.5)
        sm = ev.dtft(d - 0.5)
        d = np.clip(d + 0.5 * np.real(_safe_ratio(sp + sm, sp - sm)), -0.75, 0.75)
    return ((ev.f0 + d) * b.zero_pad).reshape(b.pb.shape)


def _real_tone_fit(ev: _DtftNearBin, d: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Least-squares energy of the best real sinusoid a cos(wn) + b sin(wn) at w = 2 pi (k+d+o)/N,
    for each offset o of ``offsets`` (rows of the result).

    For a real ramp this (not |X|^2) is the likelihood: it accounts for the tone's own
    negative-frequency image, which otherwise pulls the periodogram peak by ~1/(2 pi^2 k) bins.
    The sines and cosines are taken once at d and turned by the offsets' fixed angles (angle
    addition): a third of the transcendental calls of evaluating each offset alone (they
    were half the estimator's iteration time).
    """
    n = ev.n
    o = np.asarray(offsets, dtype=np.float64)[:, None]
    G, _, _ = ev.eval(d[None, :] + o)
    # X = exp(-j phi) G with phi = pi (d + o) (n - 1) / n
    cp, sp = _turned(np.pi * d * (n - 1) / n, np.pi * o * (n - 1) / n)
    c = cp * G.real + sp * G.imag          # Re X
    s = sp * G.real - cp * G.imag          # -Im X
    w = 2.0 * np.pi * (ev.f0 + d) / n
    eps = 2.0 * np.pi * o / n
    cw, sw = _turned(w, eps)
    cos_n1, sin_n1 = _turned(w * (n - 1), eps * (n - 1))
    sin_nw = sin_n1 * cw + cos_n1 * sw     # sin(n w) = sin((n-1) w + w)
    # sum_n exp(j 2 w n) = exp(j w (n-1)) sin(n w) / sin(w)  (-> +-n where sin(w) = 0)
    near = np.abs(sw) < 1e-12
    dirichlet = np.where(near, n * cos_n1, sin_nw / np.where(near, 1.0, sw))
    scc = 0.5 * (n + cos_n1 * dirichlet)
    sss = 0.5 * (n - cos_n1 * dirichlet)
    scs = 0.5 * sin_n1 * dirichlet
    det = scc * sss - scs**2
    ok = det > 1e-6 * n * n
    j_fit = _safe_ratio(sss * c * c - 2.0 * scs * c * s + scc * s * s, np.where(ok, det, 1.0))
    # At DC / Nyquist the sine column vanishes: one-column fit.
    return np.where(ok, j_fit, _safe_ratio(c * c, scc))


def _turned(angle: np.ndarray, by: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of ``angle`` (m,) + ``by`` (rows, 1) from one cos and sin of ``angle``."""
    ca, sa = np.cos(angle), np.sin(angle)
    cb, sb = np.cos(by), np.sin(by)
    return ca * cb - sa * sb, sa * cb + ca * sb


def _est_newton(b: _Batch, iterations: int = 3) -> np.ndarray:
    # Start from the window-aware three-bin estimate; Newton then moves at most _NEWTON_REACH.
    start = ((b.pb + _jacobsen_offset(b)) / b.zero_pad).ravel()
    # moments around the nearest whole bin (one table per distinct bin, see dtft._moments_on_bins);
    # the search is the same window around the three-bin start as before
    centre = np.rint(start)
    ev = _near(b, centre, _NEWTON_REACH + 0.51)
    d0 = start - centre
    d = d0.copy()
    h = 1e-3  # finite-difference step (bins) for the real-tone objective
    kern = None if b.iq else jit.kernels(0)     # compiled step once the DSP has loaded its kernels
    if kern is not None:
        _newton_real_compiled(ev, d, d0, h, iterations, kern)
        return ((ev.f0 + d) * b.zero_pad).reshape(b.pb.shape)
    for _ in range(iterations):
        if b.iq:
            # Complex tone: the periodogram |X|^2 is the likelihood; exact derivatives.
            G, G1, G2 = ev.eval(d, derivs=2)
            dp = 2.0 * np.real(np.conj(G) * G1)
            dpp = 2.0 * (np.abs(G1) ** 2 + np.real(np.conj(G) * G2))
        else:
            # the three offsets in one pass over the Taylor terms (same values as one by one)
            jm, j0, jp = _real_tone_fit(ev, d, np.array([-h, 0.0, h]))
            dp = (jp - jm) / (2.0 * h)
            dpp = (jp - 2.0 * j0 + jm) / (h * h)
        # Concave: Newton step.  Not concave (start outside the lobe top): small uphill step.
        step = np.where(dpp < 0, -_safe_ratio(dp, dpp), 0.05 * np.sign(dp))
        d = np.clip(d + np.clip(step, -0.25, 0.25), d0 - _NEWTON_REACH, d0 + _NEWTON_REACH)
    return ((ev.f0 + d) * b.zero_pad).reshape(b.pb.shape)


_NEWTON_REACH = 0.5  # bins; the start is within a few CRLB std of the answer past threshold


def _newton_real_compiled(ev: _DtftNearBin, d: np.ndarray, d0: np.ndarray, h: float, iterations: int,
                          kern) -> None:
    """The real-ramp iterations of :func:`_est_newton` with one compiled pass per iteration
    (lidard.dsp.spectrum._kernels.newton_real_step): the same values bit for bit. numpy still takes the
    sines and cosines (its vectorised ones; a compiled libm call could round differently), the
    kernel does every product and sum of :func:`_real_tone_fit` and of the step for all three
    offsets in one pass, where numpy made ~60 passes over (3, m) temporaries. Updates ``d`` in place."""
    n = ev.n
    o = np.array([-h, 0.0, h])[:, None]
    gr, gi = ev._terms()
    gr, gi = np.ascontiguousarray(gr), np.ascontiguousarray(gi)
    turn = np.empty((6, 3))
    for row, by in enumerate((np.pi * o * (n - 1) / n, 2.0 * np.pi * o / n, 2.0 * np.pi * o / n * (n - 1))):
        turn[2 * row], turn[2 * row + 1] = np.cos(by[:, 0]), np.sin(by[:, 0])
    for _ in range(iterations):
        phi = np.pi * d * (n - 1) / n
        w = 2.0 * np.pi * (ev.f0 + d) / n
        w1 = w * (n - 1)
        kern.newton_real_step(gr, gi, d, d0, o[:, 0], np.cos(phi), np.sin(phi), np.cos(w), np.sin(w),
                              np.cos(w1), np.sin(w1), turn, n, 1e-6 * n * n, _NEWTON_REACH, 2.0 * h, h * h)


ESTIMATORS: dict[str, Callable[[_Batch], np.ndarray]] = {
    "argmax": _est_argmax,
    "parabolic": _est_parabolic,
    "jacobsen": _est_jacobsen,
    "quinn2": _est_quinn2,
    "aboutanios": _est_aboutanios,
    "newton": _est_newton,
}
assert tuple(ESTIMATORS) == ESTIMATOR_NAMES


def estimate(
    x: object,
    peak_bins: object,
    method: EstimatorName = DEFAULT_METHOD,
    window: WindowName = "hann",
    zero_pad: int = 1,
    spectrum: np.ndarray | None = None,
) -> np.ndarray:
    """Refine integer peak bins to fractional bins (float64).

    x:         ramps, shape (..., N), real or complex (I/Q).
    peak_bins: signed integer bin numbers of the spectrum grid (N * zero_pad points), shape (...)
               (one peak per ramp) or (..., K) (K peaks per ramp).
    window:    the window of the spectrum the peaks were picked on (used by the bin-based methods
               and by the start of ``newton``).
    spectrum:  optional precomputed spectrum in RangeFFT layout (rfft for real x, fft-shifted for
               complex x) with the same window and zero_pad, to avoid recomputing it.
    Returns fractional bin numbers with the shape of ``peak_bins``.
    """
    if method not in ESTIMATORS:
        raise DspInputError(f"method={method!r} is not an estimator; choose one of {ESTIMATOR_NAMES}")
    check_window_name(window)
    if int(zero_pad) != zero_pad or zero_pad < 1:
        raise DspInputError(f"zero_pad={zero_pad!r} must be an integer >= 1")
    a = check_samples(x)
    if a.shape[-1] < 8:
        raise DspInputError(f"x has {a.shape[-1]} samples per ramp; at least 8 are needed")
    pb = np.asarray(peak_bins)
    if pb.dtype.kind not in "iu":
        if pb.dtype.kind == "f" and np.all(np.isfinite(pb)) and np.all(pb == np.rint(pb)):
            pb = pb.astype(np.int64)
        else:
            raise DspInputError(f"peak_bins must be integers, got dtype {pb.dtype}")
    lead = a.shape[:-1]
    if pb.shape == lead:
        out_shape = lead
    elif pb.ndim == a.ndim and pb.shape[:-1] == lead:
        out_shape = pb.shape
    else:
        raise DspInputError(f"peak_bins shape {pb.shape} does not match x shape {a.shape} (expected {lead} or {lead}+(K,))")
    n_fft = a.shape[-1] * int(zero_pad)
    if pb.size and (pb.min() < -n_fft or pb.max() > n_fft):
        raise DspInputError(f"peak_bins outside the spectrum grid of {n_fft} bins: {pb.min()}..{pb.max()}")
    if spectrum is not None:
        spectrum = np.asarray(spectrum)
        n_bins = n_fft if a.dtype.kind == "c" else n_fft // 2 + 1
        if spectrum.shape != lead + (n_bins,):
            raise DspInputError(f"spectrum shape {spectrum.shape} does not match x: expected {lead + (n_bins,)}")
    if pb.size == 0:
        return np.zeros(out_shape, dtype=np.float64)
    batch = _Batch(a, pb, window, int(zero_pad), spectrum)
    return np.asarray(ESTIMATORS[method](batch), dtype=np.float64).reshape(out_shape)


# estimators that read the ramps only through the spectrum's three bins and the moments
_ROW_METHODS = frozenset({"argmax", "parabolic", "jacobsen", "aboutanios", "newton"})


def estimate_rows(x: np.ndarray, rows: np.ndarray, peak_bins: np.ndarray, *, method: EstimatorName = DEFAULT_METHOD,
                  window: WindowName = "hann", zero_pad: int = 1, spectrum: np.ndarray | None = None) -> np.ndarray:
    """``estimate(x[rows], peak_bins, ..., spectrum=spectrum[rows])`` without copying those rows.

    For the detection chain (:mod:`lidard.dsp.chain`), which refines a few slots of many ramps:
    ``x`` (M, N) ramps the chain already checked (their spectrum went through CFAR), ``spectrum``
    (M, n_bins) theirs, ``rows`` (m,) and ``peak_bins`` (m,) one peak each. Copying every refined
    ramp and its whole spectrum cost as much as the estimator's moments. Methods that
    transform the ramps themselves, or a missing spectrum, take the copying path.
    """
    rows = np.asarray(rows, dtype=np.int64)
    if method not in _ROW_METHODS or spectrum is None or x.ndim != 2:
        return estimate(x[rows], peak_bins, method=method, window=window, zero_pad=zero_pad,
                        spectrum=None if spectrum is None else spectrum[rows])
    check_window_name(window)
    pb = np.asarray(peak_bins, dtype=np.int64)
    n_fft = x.shape[-1] * int(zero_pad)
    if pb.shape != rows.shape or spectrum.shape[0] != x.shape[0]:
        raise DspInputError(f"peak_bins {pb.shape} / rows {rows.shape} / spectrum {spectrum.shape} do not match "
                            f"x {x.shape}")
    if pb.size == 0:
        return np.zeros(0)
    if pb.min() < -n_fft or pb.max() > n_fft:
        raise DspInputError(f"peak_bins outside the spectrum grid of {n_fft} bins: {pb.min()}..{pb.max()}")
    out = np.asarray(ESTIMATORS[method](_Batch(x, pb, window, int(zero_pad), spectrum, rows=rows)),
                     dtype=np.float64).reshape(pb.shape)
    if not np.all(np.isfinite(out)):   # a NaN or infinite sample in a refined ramp shows here
        raise DspInputError("x contains NaN or infinite samples in a refined ramp")
    return out


def pooled_jacobsen(spec: np.ndarray, peak_bins: np.ndarray, *, window: WindowName, n_samples: int,
                    zero_pad: int = 1, iq: bool = False) -> np.ndarray:
    """One three-bin estimate per pixel from all its records: the start of the pixel's likelihood
    refinement (:func:`lidard.dsp.ranging.tones.refine_joint` over the records).

    ``spec`` (P, L, n_bins) the records' windowed spectra (RangeFFT layout), ``peak_bins`` (P, K) signed
    bins of the spectrum grid. Each record's Jacobsen ratio r_l = Re(N_l / D_l) (N = X[-1] - X[+1],
    D = 2 X[0] - X[-1] - X[+1]) has the same noise-free value r(delta) whatever the record's amplitude
    and phase, so the records pool by least squares, r = Re(sum_l N_l conj(D_l)) / sum_l |D_l|^2 (a
    weak record weighs by its power, not as one vote in ten), mapped to the offset through the
    window's table as ``jacobsen`` does. Returns fractional bins (P, K) of the spectrum grid."""
    p_n, l_n, n_bins = spec.shape
    pb = np.asarray(peak_bins, dtype=np.int64)
    k = pb.shape[-1]
    n_fft = n_bins if iq else 2 * (n_bins - 1)
    idx = np.broadcast_to((pb[:, None, :, None] + np.array([-1, 0, 1])), (p_n, l_n, k, 3)).reshape(p_n * l_n, 3 * k)
    v = gather_bins(spec.reshape(p_n * l_n, n_bins), idx, n_fft, iq).reshape(p_n, l_n, k, 3)
    num = v[..., 0] - v[..., 2]
    den = 2.0 * v[..., 1] - v[..., 0] - v[..., 2]
    r = _safe_ratio(np.real(np.sum(num * np.conj(den), axis=1)), np.sum(den.real ** 2 + den.imag ** 2, axis=1))
    r_tab, d_tab = _jacobsen_table(window, n_samples, int(zero_pad))
    return pb + np.interp(r, r_tab, d_tab)

