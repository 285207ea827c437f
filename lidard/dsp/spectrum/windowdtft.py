"""The DTFT of a window near a spectral peak, in closed form (§2.1).

W(x) = sum_t w[t] exp(-j 2 pi x t / n) of a periodic cosine-sum window (x in bins of the n-point
grid) is a sum of shifted Dirichlet kernels: the Jacobsen table, the model-order test and the skirt
search of :mod:`lidard.dsp.ranging` read it at many points. The kernels shifted by whole bins share
their numerator's sine and their phase up to a sign and a fixed rotation, which the functions here
take once (the transcendentals were most of the model-order test's time). A window that is not a
known cosine sum is summed directly. Pure numpy.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from lidard.dsp.spectrum import jit
from lidard.dsp.spectrum.window import get_window


# Periodic cosine-sum windows, w[t] = sum_k c_k cos(2 pi k t / n): their DTFT is a sum of shifted
# Dirichlet kernels, so the table below costs O(grid x terms) instead of O(grid x n) (the direct
# sum took 11.5 s for the first scan at 150 m). Checked against get_window before use.
_COSINE_SUM: dict[str, tuple[float, ...]] = {
    "rectangular": (1.0,),
    "hann": (0.5, -0.5),
    "blackmanharris": (0.35875, -0.48829, 0.14128, -0.01168),
}


def _dirichlet(x_bins: np.ndarray, n: int) -> np.ndarray:
    """sum_{t<n} exp(-j 2 pi x t / n) for x in bins of the n-point grid (-> n at x = 0 mod n).

    = exp(-j pi x (n-1)/n) sin(pi x) / sin(pi x / n). The phase factor is built from a real cosine and
    sine (numpy's complex exp is a scalar loop, several times slower), and the limit at the grid's
    multiples (at x = m n the sum is n exp(-j pi m (n-1)) times (-1)^(m(n-1)): n exactly) is taken
    only where the denominator vanishes."""
    a = np.pi * np.asarray(x_bins, dtype=np.float64)
    den = np.sin(a / n)
    near = np.abs(den) < 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.sin(a, out=np.empty(a.shape))
        ratio /= den
    if near.any():
        an = a[near]
        ratio[near] = n * np.cos(an) / np.cos(an / n)
    b = a * (n - 1)
    b /= n
    out = np.empty(a.shape, dtype=np.complex128)
    np.multiply(np.cos(b), ratio, out=out.real)
    np.multiply(np.sin(b), ratio, out=out.imag)
    np.negative(out.imag, out=out.imag)
    return out


@lru_cache(maxsize=64)
def _cosine_sum(window: str, n: int) -> tuple[float, ...] | None:
    """The window's cosine-sum coefficients when get_window gives exactly that sum at this length
    (checked once per window and length, not on every call), else None."""
    coef = _COSINE_SUM.get(window)
    if coef is None:
        return None
    t = np.arange(n)
    w = get_window(window, n)
    ok = np.allclose(sum(c * np.cos(2.0 * np.pi * k * t / n) for k, c in enumerate(coef)), w, rtol=0, atol=1e-12)
    return coef if ok else None


def _window_dtft_bins(window: str, n: int, x_bins: np.ndarray) -> np.ndarray:
    """W(x) = sum_t w[t] exp(-j 2 pi x t / n) of the periodic window, x in bins of n points."""
    coef = _cosine_sum(window, n)
    if coef is not None:
        return _cosine_sum_dtft(coef, n, np.asarray(x_bins, dtype=np.float64))
    # not a known cosine sum: direct sum, chunked to bound the (points x n) temporary
    w = get_window(window, n)
    t = np.arange(n)
    x = np.asarray(x_bins, dtype=np.float64).ravel()
    out = np.empty(x.size, dtype=np.complex128)
    step = max(1, 4_000_000 // n)
    for i in range(0, x.size, step):
        out[i:i + step] = np.exp(-2j * np.pi * np.outer(x[i:i + step], t) / n) @ w
    return out.reshape(np.shape(x_bins))


def _cosine_sum_dtft(coef: tuple[float, ...], n: int, x: np.ndarray) -> np.ndarray:
    """sum_k c_k (D(x) or (D(x - k) + D(x + k)) / 2) of a cosine-sum window with the kernels' shared factors
    taken once: D(x + m) = exp(-j phi) exp(-j pi m (n-1)/n) (-1)^m sin(pi x) / sin(pi (x + m) / n),
    phi = pi x (n-1)/n. So W(x) = sin(pi x) exp(-j phi) S(x), S = sum_m a_m (-1)^m exp(-j pi m (n-1)/n)
    / sin(pi (x + m) / n) (a_0 = c_0, a_+-k = c_k / 2): one sine of the numerator (taken on x less its
    nearest integer, exact), one phase and one sine per term's denominator, where each kernel alone
    took four transcendentals and a complex product (most of the model-order test's time). Where a
    denominator vanishes (x + m on a multiple of n) the kernels are summed one by one with their
    limits (:func:`_dirichlet`)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        out, near, terms = _cosine_sum_parts(coef, n, x)
    if near.any():
        xn = x[near]
        out[near] = sum(a * _dirichlet(xn + m, n) for m, a in terms)
    return out


def _cosine_sum_parts(coef: tuple[float, ...], n: int,
                      x: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[tuple[int, float]]]:
    """:func:`_cosine_sum_dtft` before the vanishing denominators' points are replaced (NaN there):
    (W, where a denominator vanishes, the terms (m, a_m))."""
    terms = [(0, coef[0])] + [(m, 0.5 * c) for k, c in enumerate(coef[1:], start=1) for m in (-k, k)]
    near = np.zeros(x.shape, dtype=bool)
    s_re = np.zeros(x.shape)
    s_im = np.zeros(x.shape)
    den = np.empty(x.shape)
    tmp = np.empty(x.shape)
    for m, a in terms:
        np.add(x, m, out=den)
        den *= np.pi / n
        np.sin(den, out=den)
        near |= np.abs(den) < 1e-12
        theta = np.pi * m * (n - 1) / n
        sign = -1.0 if m % 2 else 1.0
        np.divide(sign * a, den, out=tmp)
        s_re += np.cos(theta) * tmp
        tmp *= np.sin(theta)
        s_im -= tmp
    r = np.rint(x)
    num = np.subtract(x, r)
    num *= np.pi
    np.sin(num, out=num)
    num *= 1.0 - 2.0 * np.mod(r, 2.0)                    # sin(pi x) = (-1)^r sin(pi (x - r))
    phi = x * (np.pi * (n - 1) / n)
    c, s = np.cos(phi), np.sin(phi)
    # exp(-j phi) S = (c S_re + s S_im) + j (c S_im - s S_re)
    out = np.empty(x.shape, dtype=np.complex128)
    np.multiply(c, s_re, out=out.real)
    out.real += s * s_im
    np.multiply(c, s_im, out=out.imag)
    out.imag -= s * s_re
    out.real *= num
    out.imag *= num
    return out, near, terms


def _grid_terms(den: np.ndarray, factors: list[tuple[int, float, float]], q_n: int, cq: np.ndarray, sq: np.ndarray,
                num: np.ndarray, c: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_window_dtft_grid`'s cells (..., R, Q) from the denominators' sines ``den`` (..., R, J),
    each term's (first column, signed coefficient, phase theta_m) and the whole bins' and the first
    cells' factors; and where a denominator vanishes (inf or NaN there)."""
    inv = 1.0 / den
    near_den = np.abs(den) < 1e-12
    s_re = np.zeros(den.shape[:-1] + (q_n,))
    s_im = np.zeros(den.shape[:-1] + (q_n,))
    near = np.zeros(den.shape[:-1] + (q_n,), dtype=bool)
    for j0, coef_m, theta in factors:
        sl = slice(j0, j0 + q_n)
        s_re += (coef_m * np.cos(theta)) * inv[..., sl]
        s_im -= (coef_m * np.sin(theta)) * inv[..., sl]
        near |= near_den[..., sl]
    t_re = cq * s_re + sq * s_im
    t_im = cq * s_im - sq * s_re
    c, s = c[..., None], s[..., None]
    out = np.empty(t_re.shape, dtype=np.complex128)
    np.multiply(c, t_re, out=out.real)
    out.real += s * t_im
    np.multiply(c, t_im, out=out.imag)
    out.imag -= s * t_re
    out.real *= num[..., None]
    out.imag *= num[..., None]
    return out, near


def _window_dtft_grid(window: str, n: int, x0: np.ndarray, m: int, zero_pad: int) -> np.ndarray:
    """W(x0 + i / zero_pad) for i < m (..., m): the window's DTFT on m consecutive cells of a spectrum
    zero-padded ``zero_pad`` times, from each start ``x0`` (...,) (bins of the n-point grid).

    The cells are a whole bin apart every ``zero_pad`` of them, and a whole bin changes the Dirichlet
    kernels' common factors by a sign and a fixed phase only (:func:`_cosine_sum_dtft`): the numerator's
    sine and the phase are taken on the first ``zero_pad`` cells, and each denominator sine once for
    the kernels that share it (m + 2 L sines for L cosine terms, where each cell alone took 2 L + 4).
    Not a cosine sum: :func:`_window_dtft_bins` on every cell."""
    x0 = np.asarray(x0, dtype=np.float64)
    coef = _cosine_sum(window, n)
    zp = int(zero_pad)
    if coef is None:
        return _window_dtft_bins(window, n, x0[..., None] + np.arange(m) / zp)
    terms = [(0, coef[0])] + [(mm, 0.5 * c) for k, c in enumerate(coef[1:], start=1) for mm in (-k, k)]
    reach = len(coef) - 1
    with np.errstate(divide="ignore", invalid="ignore"):   # NaN where a denominator vanishes: replaced below
        r_n, q_n = min(zp, m), -(-m // zp)
        y = x0[..., None] + np.arange(r_n) / zp                              # (..., R): the first cells
        den = np.sin((y[..., None] + np.arange(-reach, q_n + reach)) * (np.pi / n))       # (..., R, J)
        # T = (-1)^q exp(-j psi_q) S, psi_q = pi q (n-1)/n: the q-th whole bin's sign and phase
        q = np.arange(q_n)
        cq = np.where(q % 2, -1.0, 1.0) * np.cos(np.pi * q * (n - 1) / n)
        sq = np.where(q % 2, -1.0, 1.0) * np.sin(np.pi * q * (n - 1) / n)
        r = np.rint(y)
        num = np.sin(np.pi * (y - r)) * (1.0 - 2.0 * np.mod(r, 2.0))         # sin(pi y), (..., R)
        phi = y * (np.pi * (n - 1) / n)
        c, s = np.cos(phi), np.sin(phi)
        factors = [(mm + reach, -a if mm % 2 else a, np.pi * mm * (n - 1) / n) for mm, a in terms]
        kern = jit.kernels(0)
        if kern is not None and y.size:    # the arithmetic below in one compiled pass (the same values)
            out = np.empty(y.shape + (q_n,), dtype=np.complex128)
            near = np.empty(out.shape, dtype=bool)
            kern.window_grid(den.reshape((-1,) + den.shape[-2:]), np.array([f[0] for f in factors], dtype=np.int64),
                             np.array([cm * np.cos(th) for _, cm, th in factors]),
                             np.array([cm * np.sin(th) for _, cm, th in factors]), cq, sq,
                             num.reshape(-1, r_n), c.reshape(-1, r_n), s.reshape(-1, r_n),
                             out.reshape((-1,) + out.shape[-2:]), near.reshape((-1,) + near.shape[-2:]))
        else:
            out, near = _grid_terms(den, factors, q_n, cq, sq, num, c, s)
    if near.any():          # a denominator vanishes: those cells one by one, with the kernels' limits
        out[near] = _cosine_sum_dtft(coef, n, np.broadcast_to(y[..., None] + q, near.shape)[near])
    # (..., R, Q) -> cell i = q zero_pad + r
    return np.swapaxes(out, -1, -2).reshape(x0.shape + (r_n * q_n,))[..., :m]
