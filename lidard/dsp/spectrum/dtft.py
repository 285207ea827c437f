"""The DTFT near a spectral peak, shared by the sub-bin estimators (:mod:`lidard.dsp.ranging.estimators`; §2.1).

Two tools: the noise-free Jacobsen ratio r(delta) of a window, length and zero-padding, built from the
window's DTFT (:mod:`lidard.dsp.spectrum.windowdtft`), and X(f0 + delta) with
its first two derivatives for many ramps at once (:class:`_DtftNearBin`), which the ``aboutanios``
and ``newton`` estimators iterate on.

DTFT values near a start frequency f0 (bins of the N-point grid) are evaluated through moments:
with the ramp demodulated by f0, z[n] = x[n] exp(-j 2 pi f0 n / N), and s = (n - (N-1)/2) / ((N-1)/2),
X(f0 + delta) = exp(-j pi delta (N-1)/N) * sum_p mu_p (-j a delta)^p / p!,  mu_p = sum_n z[n] s^p,
a = pi (N-1)/N.  The moments are one small real matrix product per batch; afterwards X, dX/ddelta
and d2X/ddelta2 at any offset are polynomial evaluations, so Newton steps cost O(terms) per ramp.

The product does not read the ramps against s^p itself but against the Chebyshev polynomials T_q(s)
(fewer moments for the same accuracy): by Jacobi-Anger, exp(-j a delta s) = sum_q eps_q (-j)^q J_q(a delta) T_q(s), and J_q falls
off like (a delta / 2)^q / q!, so Q Chebyshev moments nu_q = sum_n z[n] T_q(s) carry what ~1.4 Q power
moments do (20 against 26 for |delta| <= 1 bin at 1e-13). mu_p follows from them exactly for p < Q
(s^p = 2^(1-p) sum' C(p, m) T_(p-2m)(s)) and with the part of s^p beyond T_(Q-1) dropped for p >= Q,
which changes X by less than the Bessel tail. The ramps are read once, by the smaller product.
"""

from __future__ import annotations

from functools import lru_cache
from math import comb, factorial

import numpy as np

from lidard.dsp.spectrum import jit
from lidard.dsp.spectrum.windowdtft import _window_dtft_bins

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
    """Chebyshev basis T_q(s) (n x Q) and the real (2P x 2Q) map from the Chebyshev moments' parts to the
    Taylor coefficients' parts in delta: g_p = (-j a)^p / p! mu_p with mu = nu @ R (R: Chebyshev to
    power moments, P = ``n_terms``)."""
    t = np.arange(n, dtype=np.float64)
    half = (n - 1) / 2.0
    s = (t - half) / half
    a = 2.0 * np.pi * half / n
    q_terms = min(n_terms, _chebyshev_terms_for(n_terms))
    basis = np.empty((n, q_terms))
    basis[:, 0] = 1.0
    if q_terms > 1:
        basis[:, 1] = s
    for q in range(2, q_terms):     # the three-term recurrence: |T_q| <= 1, no cancellation
        basis[:, q] = 2.0 * s * basis[:, q - 1] - basis[:, q - 2]
    # s^p = 2^-p sum_{m=0}^{p} C(p, m) T_|p-2m|(s): the coefficient of T_q (q = p - 2m >= 0) is
    # eps_q C(p, m) / 2^p (eps_0 = 1, else 2: T_-q = T_q pairs the terms m and p - m)
    cheb_to_power = np.zeros((q_terms, n_terms))
    for p in range(n_terms):
        for m in range(p // 2 + 1):
            q = p - 2 * m
            if q < q_terms:
                cheb_to_power[q, p] = (1.0 if q == 0 else 2.0) * comb(p, m) / 2.0 ** p
    coef = np.array([(-1j * a) ** p / factorial(p) for p in range(n_terms)])
    # g = (nu @ R) * coef for complex nu, as one real map of the parts: [Re g; Im g] = M [Re nu; Im nu]
    rc = cheb_to_power * coef              # (Q, P) complex
    coef_map = np.ascontiguousarray(np.block([[rc.real.T, -rc.imag.T], [rc.imag.T, rc.real.T]]))
    for arr in (basis, coef_map):
        arr.setflags(write=False)
    return basis, coef_map


def _chebyshev_terms_for(n_terms: int) -> int:
    """Chebyshev moments Q for the reach that ``n_terms`` Taylor terms were chosen for (:func:`_terms_for`):
    the smallest Q with 2 sum_{q >= Q} (x/2)^q / q! < 1e-13 (a bound of the Jacobi-Anger tail
    2 sum |J_q(x)|), x = pi * reach."""
    x = np.pi * _reach_of_terms(n_terms)
    q = 0
    while 2.0 * sum((x / 2.0) ** k / factorial(k) for k in range(q, q + 40)) >= 1e-13:
        q += 1
    return max(q, 2)


def _small_gemm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b as a stack of products of a few rows each.

    OpenBLAS runs one large product on all its threads; these products are too small for that to
    pay, and on a busy 2-core host the woken threads spin and wait for a core (about half the CPU
    time of the frame DSP went there). A stacked matmul calls BLAS per block, and a block below
    OpenBLAS's multithreading threshold runs on the calling thread. OpenBLAS 0.3.2x+ (numpy's wheels)
    gives a product M*N*K / 2.6e5 threads, so blocks under 5.2e5 stay on one (measured with numpy
    2.4's OpenBLAS 0.3.31: 1.0e6 still one thread, 1.2e6 two); 5e5 rather than 2e5:
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


def _small_gemm_by_columns(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b.T for a small ``a`` (r, k) and many rows of ``b`` (m, k), as products of a few hundred
    columns each: one large product would wake every OpenBLAS thread (see :func:`_small_gemm`)."""
    r, k = a.shape
    m = b.shape[0]
    out = np.empty((r, m))
    step = max(1, _GEMM_BLOCK_MNK // max(1, r * k))
    for i in range(0, m, step):
        np.matmul(a, b[i:i + step].T, out=out[:, i:i + step])
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
        basis, coef_map = _moment_basis(n, n_terms)
        if f0.size and np.all(f0 == np.rint(f0)):
            nu = _moments_on_bins(x, rows, f0, basis)
        else:
            nu = _moments_off_grid(x, rows, f0, basis)
        # G(delta) = sum_p g[p] delta^p with g = (nu @ R) * coef: one real product from the moments'
        # parts (m, 2Q) to the coefficients' parts, term-major as eval reads them (2P, m)
        gt = _small_gemm_by_columns(coef_map, nu.reshape(f0.size, -1))
        self._gt = (gt[:n_terms], gt[n_terms:])

    def eval(self, delta: np.ndarray, derivs: int = 0, cols: np.ndarray | None = None):
        """G, G', G'' at ``delta`` by Horner; X = exp(-j pi delta (n-1)/n) G.

        ``delta`` (..., m) for the m pairs: several offsets per pair in one pass (the leading axes).
        Real and imaginary parts run as separate real arrays: a complex array times a real ``delta``
        is a full complex product in numpy (four multiplications, two of them by zero); the parts
        give the same values with half the work. ``cols``: evaluate only these pairs
        (``delta`` (..., len(cols))).
        """
        gr, gi = self._terms()
        if cols is not None:        # only these pairs (an iteration's pixels still moving)
            gr, gi = gr[:, cols], gi[:, cols]
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
        return self._gt

    def dtft(self, delta: np.ndarray, cols: np.ndarray | None = None) -> np.ndarray:
        G, _, _ = self.eval(delta, cols=cols)
        return np.exp(-1j * np.pi * delta * (self.n - 1) / self.n) * G


def _moments_off_grid(x: np.ndarray, rows: np.ndarray | None, f0: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """The Chebyshev moments (m, 2, Q) (real, imaginary parts) around fractional bins f0, one each."""
    n, q_terms = basis.shape
    # exp(-j 2 pi f0 t / n) as an outer product over t = n2 a + b: n1 + n2 complex exponentials
    # per ramp instead of n (the per-ramp twiddle dominated the cost otherwise).
    n2 = int(np.ceil(np.sqrt(n)))
    n1 = -(-n // n2)
    a_idx = np.arange(n1) * n2
    b_idx = np.arange(n2)
    nu = np.empty((f0.size, 2, q_terms))
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
        nu[sl, 0] = r[:m]
        nu[sl, 1] = r[m:]
    return nu


@lru_cache(maxsize=8)
def _twiddle_table(n: int) -> np.ndarray:
    """exp(-j 2 pi m / n), m = 0..n-1, as (n, 2) [cos, sin] (the demodulation of any whole bin is a
    lookup at k t mod n: no complex exponential per bin)."""
    w = np.exp((-2j * np.pi / n) * np.arange(n))
    out = np.ascontiguousarray(np.stack([w.real, w.imag], axis=1))
    out.setflags(write=False)
    return out


def _moments_on_bins(x: np.ndarray, rows: np.ndarray | None, f0: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """The Chebyshev moments (m, 2, Q) around whole bins f0, grouped by bin.

    Around a whole bin k the demodulated basis T_q(s) exp(-j 2 pi k t / N) is the same for every ramp
    whose peak is at k, so each distinct bin costs one (N x 2Q) table and its ramps one real matrix
    product, with no per-ramp twiddle (which cost several times the product itself). A frame has
    far fewer distinct peak bins (<= N/2) than ramps.
    """
    n, q_terms = basis.shape
    k = f0.astype(np.int64)
    nu = np.empty((k.size, 2, q_terms))
    order = np.argsort(k, kind="stable")
    ks = k[order]
    cuts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1], True])
    t = np.arange(n)
    tw = _twiddle_table(n)
    is_complex = x.dtype.kind == "c"
    table = np.empty((n, 2, q_terms))
    kern = jit.kernels(0)       # the compiled table once the DSP has loaded its kernels (the same products)
    for a, b in zip(cuts[:-1], cuts[1:]):
        idx = order[a:b]
        # (N, 2Q) real: cos and sin of the twiddle times the basis (the parts of exp(j phi) T_q)
        if kern is not None:
            kern.bin_table(tw, basis, int(ks[a]), table)
        else:
            np.multiply(tw[(ks[a] * t) % n][:, :, None], basis[:, None, :], out=table)
        xs = x[idx] if rows is None else x[rows[idx]]
        tab = table.reshape(n, 2 * q_terms)
        if is_complex:   # (xr + j xi)(Br + j Bi)
            r = _small_gemm(np.concatenate([xs.real, xs.imag]), tab).reshape(2, idx.size, 2, q_terms)
            nu[idx, 0] = r[0, :, 0] - r[1, :, 1]
            nu[idx, 1] = r[0, :, 1] + r[1, :, 0]
        else:
            nu[idx] = _small_gemm(np.ascontiguousarray(xs, dtype=np.float64), tab).reshape(idx.size, 2, q_terms)
    return nu


def _terms_for(max_abs_delta: float) -> int:
    """Taylor terms so that (pi D)^P / P! < 1e-12 (relative error of X far below any noise)."""
    z = np.pi * max_abs_delta
    p, term = 0, 1.0
    while term > 1e-12 or p < 4:
        p += 1
        term *= z / p
    return p + 1


def _reach_of_terms(n_terms: int) -> float:
    """The largest |delta| that ``n_terms`` Taylor terms cover (the inverse of :func:`_terms_for`, whose
    loop stops at the first P - 1 with (pi D)^(P-1) / (P-1)! <= 1e-12)."""
    k = n_terms - 1
    return (1e-12 * factorial(k)) ** (1.0 / k) / np.pi
