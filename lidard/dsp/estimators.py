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

DTFT values near a start frequency f0 (bins of the N-point grid) are evaluated through moments:
with the ramp demodulated by f0, z[n] = x[n] exp(-j 2 pi f0 n / N), and s = (n - (N-1)/2) / ((N-1)/2),
X(f0 + delta) = exp(-j pi delta (N-1)/N) * sum_p mu_p (-j a delta)^p / p!,  mu_p = sum_n z[n] s^p,
a = pi (N-1)/N.  The moments are one small real matrix product per batch; afterwards X, dX/ddelta
and d2X/ddelta2 at any offset are polynomial evaluations, so Newton steps cost O(terms) per ramp.

Known limits: ``quinn2`` and ``aboutanios`` treat a real ramp's negative-frequency image as
interference, so close to DC or Nyquist they carry a bias of order 1/(2 pi k) bins (``newton``
models the image); a second target inside the main lobe biases every method.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from math import factorial
from typing import Literal, get_args

import numpy as np

from lidard.dsp.rangefft import check_samples, gather_bins, windowed_fft
from lidard.dsp.window import DspInputError, WindowName, check_window_name, get_window

EstimatorName = Literal["argmax", "parabolic", "jacobsen", "quinn2", "aboutanios", "newton"]
ESTIMATOR_NAMES: tuple[str, ...] = get_args(EstimatorName)
DEFAULT_METHOD: EstimatorName = "newton"

_CHUNK_ROWS = 4096  # bounds the (rows x N) temporaries of the moment computation


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------
class _Batch:
    """Flattened view of a call: rows of samples, one peak per (row, k) and the spectrum grid."""

    def __init__(self, x: np.ndarray, peak_bins: np.ndarray, window: str, zero_pad: int, spectrum):
        self.x = x.reshape(-1, x.shape[-1])
        self.n = x.shape[-1]
        self.zero_pad = zero_pad
        self.n_fft = self.n * zero_pad
        self.iq = x.dtype.kind == "c"
        self.window = window
        self.pb = peak_bins.reshape(self.x.shape[0], -1).astype(np.int64)
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
        v = gather_bins(spec, idx, n_fft, self.iq).reshape(m, k, 3)
        return v[..., 0], v[..., 1], v[..., 2]


def _safe_ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """num/den with 0 where the denominator vanishes (all-zero or constant ramps)."""
    ok = np.abs(den) > 0
    out = np.zeros(np.broadcast(num, den).shape, dtype=np.result_type(num, den))
    np.divide(num, den, out=out, where=ok)
    return out


def _jacobsen_ratio(xm, x0, xp) -> np.ndarray:
    return np.real(_safe_ratio(xm - xp, 2.0 * x0 - xm - xp))


# Periodic cosine-sum windows, w[t] = sum_k c_k cos(2 pi k t / n): their DTFT is a sum of shifted
# Dirichlet kernels, so the table below costs O(grid x terms) instead of O(grid x n) (the direct
# sum took 11.5 s for the first scan at 150 m). Checked against get_window before use.
_COSINE_SUM: dict[str, tuple[float, ...]] = {
    "rectangular": (1.0,),
    "hann": (0.5, -0.5),
    "blackmanharris": (0.35875, -0.48829, 0.14128, -0.01168),
}


def _dirichlet(x_bins: np.ndarray, n: int) -> np.ndarray:
    """sum_{t<n} exp(-j 2 pi x t / n) for x in bins of the n-point grid (-> n at x = 0 mod n)."""
    den = np.sin(np.pi * x_bins / n)
    near = np.abs(den) < 1e-12
    # at x = m n the sum is n exp(-j pi m (n-1)) times (-1)^(m(n-1)): n exactly
    ratio = np.where(near, n * np.cos(np.pi * x_bins) / np.where(near, np.cos(np.pi * x_bins / n), 1.0),
                     np.sin(np.pi * x_bins) / np.where(near, 1.0, den))
    return np.exp(-1j * np.pi * x_bins * (n - 1) / n) * ratio


def _window_dtft_bins(window: str, n: int, x_bins: np.ndarray) -> np.ndarray:
    """W(x) = sum_t w[t] exp(-j 2 pi x t / n) of the periodic window, x in bins of n points."""
    w = get_window(window, n)
    coef = _COSINE_SUM.get(window)
    t = np.arange(n)
    if coef is not None and np.allclose(
            sum(c * np.cos(2.0 * np.pi * k * t / n) for k, c in enumerate(coef)), w, rtol=0, atol=1e-12):
        x = np.asarray(x_bins, dtype=np.float64)
        out = coef[0] * _dirichlet(x, n)
        for k, c in enumerate(coef[1:], start=1):
            out = out + 0.5 * c * (_dirichlet(x - k, n) + _dirichlet(x + k, n))
        return out
    # not a known cosine sum: direct sum, chunked to bound the (points x n) temporary
    x = np.asarray(x_bins, dtype=np.float64).ravel()
    out = np.empty(x.size, dtype=np.complex128)
    step = max(1, 4_000_000 // n)
    for i in range(0, x.size, step):
        out[i:i + step] = np.exp(-2j * np.pi * np.outer(x[i:i + step], t) / n) @ w
    return out.reshape(np.shape(x_bins))


@lru_cache(maxsize=64)
def _jacobsen_table(window: str, n: int, zero_pad: int) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free r(delta) of the given window/length/padding, delta in bins of the padded grid."""
    delta = np.linspace(-0.98, 0.98, 1961)
    # Complex tone at bin offset delta, seen at bins -1, 0, +1 of the padded grid: the window's
    # DTFT at (m - delta) padded bins = (m - delta) / zero_pad bins of the n-point grid.
    cols = [_window_dtft_bins(window, n, (m - delta) / zero_pad) for m in (-1, 0, 1)]
    r = _jacobsen_ratio(cols[0], cols[1], cols[2])
    # Keep the monotonic branch around delta = 0 so the inverse is single-valued.
    i0 = np.argmin(np.abs(delta))
    inc = np.diff(r) > 0
    lo = i0
    while lo > 0 and inc[lo - 1]:
        lo -= 1
    hi = i0
    while hi < inc.size and inc[hi]:
        hi += 1
    r_tab, d_tab = r[lo : hi + 1].copy(), delta[lo : hi + 1].copy()
    r_tab.setflags(write=False)
    d_tab.setflags(write=False)
    return r_tab, d_tab


@lru_cache(maxsize=32)
def _moment_basis(n: int, n_terms: int) -> tuple[np.ndarray, np.ndarray]:
    """s^p basis (n x n_terms) and the (-j a)^p / p! coefficients of the Taylor expansion."""
    t = np.arange(n, dtype=np.float64)
    half = (n - 1) / 2.0
    s = (t - half) / half
    basis = np.ascontiguousarray(np.vander(s, n_terms, increasing=True))
    a = 2.0 * np.pi * half / n
    coef = np.array([(-1j * a) ** p / factorial(p) for p in range(n_terms)])
    for arr in (basis, coef):
        arr.setflags(write=False)
    return basis, coef


def _small_gemm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b as a stack of products of a few rows each.

    OpenBLAS runs one large product on all its threads; these products are too small for that to
    pay, and on a busy 2-core host the woken threads spin and wait for a core (about half the CPU
    time of the frame DSP went there). A stacked matmul calls BLAS per block, and a block below
    OpenBLAS's multithreading threshold (M*N*K ~ 2.6e5) runs on the calling thread. Same sums.
    """
    rows, n = a.shape
    g = max(1, min(64, 200_000 // max(1, n * b.shape[1])))
    full = rows // g * g
    out = np.empty((rows, b.shape[1]), dtype=np.result_type(a, b))
    if full:
        out[:full] = (a[:full].reshape(-1, g, n) @ b).reshape(full, b.shape[1])
    if full < rows:
        out[full:] = a[full:] @ b
    return out


class _DtftNearBin:
    """X(f0 + delta) and its first two delta-derivatives for many (ramp, f0) pairs at once.

    f0 is any (fractional) frequency in bins of the N-point grid; the ramp is demodulated by it
    exactly, so the Taylor series in delta only has to cover the refinement, not the whole bin.
    """

    def __init__(self, x: np.ndarray, rows: np.ndarray | None, f0: np.ndarray, n_terms: int):
        n = x.shape[-1]
        self.n = n
        self.f0 = f0
        basis, coef = _moment_basis(n, n_terms)
        # exp(-j 2 pi f0 t / n) as an outer product over t = n2 a + b: n1 + n2 complex exponentials
        # per ramp instead of n (the per-ramp twiddle dominated the cost otherwise).
        n2 = int(np.ceil(np.sqrt(n)))
        n1 = -(-n // n2)
        a_idx = np.arange(n1) * n2
        b_idx = np.arange(n2)
        mu = np.empty((f0.size, n_terms), dtype=np.complex128)
        is_complex = x.dtype.kind == "c"
        for i in range(0, f0.size, _CHUNK_ROWS):
            sl = slice(i, min(i + _CHUNK_ROWS, f0.size))
            m = sl.stop - sl.start
            ph = (-2.0 * np.pi / n) * np.mod(f0[sl], n)[:, None]
            u = np.exp(1j * ph * a_idx)
            v = np.exp(1j * ph * b_idx)
            tw = (u[:, :, None] * v[:, None, :]).reshape(m, n1 * n2)[:, :n]
            xs = x[sl] if rows is None else x[rows[sl]]
            # Real and imaginary parts stacked as rows of one real matrix: one GEMM with half the
            # flops of a complex or interleaved product.
            z = np.empty((2, m, n))
            if is_complex:
                np.multiply(xs.real, tw.real, out=z[0])
                z[0] -= xs.imag * tw.imag
                np.multiply(xs.real, tw.imag, out=z[1])
                z[1] += xs.imag * tw.real
            else:
                np.multiply(xs, tw.real, out=z[0])
                np.multiply(xs, tw.imag, out=z[1])
            r = _small_gemm(z.reshape(2 * m, n), basis)
            mu[sl].real = r[:m]
            mu[sl].imag = r[m:]
        # G(delta) = sum_p g[p] delta^p
        self.g = mu * coef

    def eval(self, delta: np.ndarray, derivs: int = 0):
        """G, G', G'' at ``delta`` by Horner; X = exp(-j pi delta (n-1)/n) G."""
        g = self.g
        G = np.zeros(delta.shape, dtype=np.complex128)
        G1 = np.zeros_like(G)
        G2 = np.zeros_like(G)
        for p in range(g.shape[1] - 1, -1, -1):
            if derivs >= 2:
                G2 = G2 * delta + 2.0 * G1
            if derivs >= 1:
                G1 = G1 * delta + G
            G = G * delta + g[:, p]
        return G, G1, G2

    def dtft(self, delta: np.ndarray) -> np.ndarray:
        G, _, _ = self.eval(delta)
        return np.exp(-1j * np.pi * delta * (self.n - 1) / self.n) * G


def _terms_for(max_abs_delta: float) -> int:
    """Taylor terms so that (pi D)^P / P! < 1e-12 (relative error of X far below any noise)."""
    z = np.pi * max_abs_delta
    p, term = 0, 1.0
    while term > 1e-12 or p < 4:
        p += 1
        term *= z / p
    return p + 1


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


def _real_tone_fit(ev: _DtftNearBin, d: np.ndarray) -> np.ndarray:
    """Least-squares energy of the best real sinusoid a cos(wn) + b sin(wn) at w = 2 pi (k+d)/N.

    For a real ramp this (not |X|^2) is the likelihood: it accounts for the tone's own
    negative-frequency image, which otherwise pulls the periodogram peak by ~1/(2 pi^2 k) bins.
    """
    n = ev.n
    X = ev.dtft(d)
    c, s = X.real, -X.imag
    w = 2.0 * np.pi * (ev.f0 + d) / n
    # sum_n exp(j 2 w n) = exp(j w (n-1)) sin(n w) / sin(w)  (-> +-n where sin(w) = 0)
    sw = np.sin(w)
    near = np.abs(sw) < 1e-12
    dirichlet = np.where(near, n * np.cos(w * (n - 1)), np.sin(n * w) / np.where(near, 1.0, sw))
    scc = 0.5 * (n + np.cos(w * (n - 1)) * dirichlet)
    sss = 0.5 * (n - np.cos(w * (n - 1)) * dirichlet)
    scs = 0.5 * np.sin(w * (n - 1)) * dirichlet
    det = scc * sss - scs**2
    ok = det > 1e-6 * n * n
    j_fit = _safe_ratio(sss * c * c - 2.0 * scs * c * s + scc * s * s, np.where(ok, det, 1.0))
    # At DC / Nyquist the sine column vanishes: one-column fit.
    return np.where(ok, j_fit, _safe_ratio(c * c, scc))


def _est_newton(b: _Batch, iterations: int = 3) -> np.ndarray:
    # Start from the window-aware three-bin estimate; Newton then moves at most _NEWTON_REACH.
    f0 = (b.pb + _jacobsen_offset(b)) / b.zero_pad
    ev = _near(b, f0, _NEWTON_REACH + 0.01)
    d = np.zeros(ev.f0.shape)
    h = 1e-3  # finite-difference step (bins) for the real-tone objective
    for _ in range(iterations):
        if b.iq:
            # Complex tone: the periodogram |X|^2 is the likelihood; exact derivatives.
            G, G1, G2 = ev.eval(d, derivs=2)
            dp = 2.0 * np.real(np.conj(G) * G1)
            dpp = 2.0 * (np.abs(G1) ** 2 + np.real(np.conj(G) * G2))
        else:
            jm, j0, jp = (_real_tone_fit(ev, d + o) for o in (-h, 0.0, h))
            dp = (jp - jm) / (2.0 * h)
            dpp = (jp - 2.0 * j0 + jm) / (h * h)
        # Concave: Newton step.  Not concave (start outside the lobe top): small uphill step.
        step = np.where(dpp < 0, -_safe_ratio(dp, dpp), 0.05 * np.sign(dp))
        d = np.clip(d + np.clip(step, -0.25, 0.25), -_NEWTON_REACH, _NEWTON_REACH)
    return ((ev.f0 + d) * b.zero_pad).reshape(b.pb.shape)


_NEWTON_REACH = 0.5  # bins; the start is within a few CRLB std of the answer past threshold


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
