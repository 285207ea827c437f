"""The DTFT near a spectral peak, shared by the sub-bin estimators (:mod:`lidard.dsp.estimators`; §2.1).

Two tools: the noise-free Jacobsen ratio r(delta) of a window, length and zero-padding, built from the
window's DTFT (a sum of shifted Dirichlet kernels for the cosine-sum windows), and X(f0 + delta) with
its first two derivatives for many ramps at once (:class:`_DtftNearBin`), which the ``aboutanios``
and ``newton`` estimators iterate on.

DTFT values near a start frequency f0 (bins of the N-point grid) are evaluated through moments:
with the ramp demodulated by f0, z[n] = x[n] exp(-j 2 pi f0 n / N), and s = (n - (N-1)/2) / ((N-1)/2),
X(f0 + delta) = exp(-j pi delta (N-1)/N) * sum_p mu_p (-j a delta)^p / p!,  mu_p = sum_n z[n] s^p,
a = pi (N-1)/N.  The moments are one small real matrix product per batch; afterwards X, dX/ddelta
and d2X/ddelta2 at any offset are polynomial evaluations, so Newton steps cost O(terms) per ramp.
"""

from __future__ import annotations

from functools import lru_cache
from math import factorial

import numpy as np

from lidard.dsp.window import get_window

_CHUNK_ROWS = 4096  # bounds the (rows x N) temporaries of the moment computation
_GEMM_BLOCK_MNK = 500_000   # rows x columns x inner length of one BLAS call of _small_gemm (below)


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
    OpenBLAS's multithreading threshold runs on the calling thread. OpenBLAS 0.3.2x+ (numpy's wheels)
    gives a product M*N*K / 2.6e5 threads, so blocks under 5.2e5 stay on one (measured with numpy
    2.4's OpenBLAS 0.3.31: 1.0e6 still one thread, 1.2e6 two); 5e5 rather than 2e5 (issue 18):
    at N = 2880 the old budget made single-row products, each re-reading the whole table. Same sums.
    """
    rows, n = a.shape
    g = max(1, min(64, _GEMM_BLOCK_MNK // max(1, n * b.shape[1])))
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
        if f0.size and np.all(f0 == np.rint(f0)):
            self.g = _moments_on_bins(x, rows, f0, basis) * coef
            return
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
        """G, G', G'' at ``delta`` by Horner; X = exp(-j pi delta (n-1)/n) G.

        ``delta`` (..., m) for the m pairs: several offsets per pair in one pass (the leading axes).
        Real and imaginary parts run as separate real arrays: a complex array times a real ``delta``
        is a full complex product in numpy (four multiplications, two of them by zero); the parts
        give the same values with half the work (issue 18).
        """
        gr, gi = self._terms()
        delta = np.asarray(delta, dtype=np.float64)
        shape = np.broadcast_shapes(delta.shape, gr.shape[1:])
        parts = [np.zeros(shape) for _ in range(2 * (derivs + 1))]      # G, G', G'' as (re, im)
        tmp = np.empty(shape)
        # in place (the same products and sums as G = G * delta + g_p, without a temporary per term)
        for p in range(gr.shape[0] - 1, -1, -1):
            for d in range(derivs, -1, -1):         # G'' from G' and G' from G before they move on
                for part in (0, 1):
                    acc = parts[2 * d + part]
                    acc *= delta
                    if d == 0:
                        acc += (gr, gi)[part][p]
                    elif d == 1:
                        acc += parts[part]
                    else:
                        np.multiply(parts[2 * (d - 1) + part], float(d), out=tmp)
                        acc += tmp
        out = []
        for d in range(3):
            z = np.zeros(shape, dtype=np.complex128)
            if d <= derivs:
                z.real, z.imag = parts[2 * d], parts[2 * d + 1]
            out.append(z)
        return tuple(out)

    def _terms(self) -> tuple[np.ndarray, np.ndarray]:
        """The coefficients term-major (P, m), real and imaginary parts, contiguous per term."""
        gt = getattr(self, "_gt", None)
        if gt is None:
            gt = self._gt = (np.ascontiguousarray(self.g.real.T), np.ascontiguousarray(self.g.imag.T))
        return gt

    def dtft(self, delta: np.ndarray) -> np.ndarray:
        G, _, _ = self.eval(delta)
        return np.exp(-1j * np.pi * delta * (self.n - 1) / self.n) * G


def _moments_on_bins(x: np.ndarray, rows: np.ndarray | None, f0: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """The moments mu_p around whole bins f0, grouped by bin (issue 18).

    Around a whole bin k the demodulated basis s^p exp(-j 2 pi k t / N) is the same for every ramp
    whose peak is at k, so each distinct bin costs one (N x 2P) table and its ramps one real matrix
    product, with no per-ramp twiddle (which cost several times the product itself). A frame has
    far fewer distinct peak bins (<= N/2) than ramps.
    """
    n, n_terms = basis.shape
    k = f0.astype(np.int64)
    mu = np.empty((k.size, n_terms), dtype=np.complex128)
    parts = mu.view(np.float64).reshape(k.size, n_terms, 2)
    order = np.argsort(k, kind="stable")
    ks = k[order]
    cuts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1], True])
    t = np.arange(n)
    is_complex = x.dtype.kind == "c"
    table = np.empty((n, 2 * n_terms))
    for a, b in zip(cuts[:-1], cuts[1:]):
        idx = order[a:b]
        # (N, 2P) real: cos and sin of the twiddle times the basis (the parts of exp(j phi) s^p)
        ph = np.exp((-2j * np.pi / n) * np.mod(ks[a], n) * t)
        np.multiply(ph.real[:, None], basis, out=table[:, :n_terms])
        np.multiply(ph.imag[:, None], basis, out=table[:, n_terms:])
        xs = x[idx] if rows is None else x[rows[idx]]
        if is_complex:   # (xr + j xi)(Br + j Bi)
            r = _small_gemm(np.concatenate([xs.real, xs.imag]), table)
            m = idx.size
            mu[idx] = (r[:m, :n_terms] - r[m:, n_terms:]) + 1j * (r[:m, n_terms:] + r[m:, :n_terms])
        else:
            r = _small_gemm(np.ascontiguousarray(xs, dtype=np.float64), table)
            parts[idx, :, 0] = r[:, :n_terms]     # the parts written in place (no complex temporaries)
            parts[idx, :, 1] = r[:, n_terms:]
    return mu


def _terms_for(max_abs_delta: float) -> int:
    """Taylor terms so that (pi D)^P / P! < 1e-12 (relative error of X far below any noise)."""
    z = np.pi * max_abs_delta
    p, term = 0, 1.0
    while term > 1e-12 or p < 4:
        p += 1
        term *= z / p
    return p + 1
