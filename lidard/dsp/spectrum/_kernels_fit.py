"""Compiled kernels of the tone-model fits (numba; loaded with :mod:`lidard.dsp.spectrum._kernels` by
:mod:`lidard.dsp.spectrum.jit`, only where numba is installed; importing this module compiles nothing).

:func:`window_grid` is the arithmetic of :func:`lidard.dsp.spectrum.windowdtft._window_dtft_grid` (the window's
DTFT on the cells the model-order test and the skirt search fit) after numpy's sines and cosines: the
same IEEE operations in the same order, bit for bit, in one pass where numpy made about twenty over
(..., cells) temporaries.

:func:`joint_stencil` is one iteration of :func:`lidard.dsp.ranging.tones.refine_joint`'s Newton search: per
pixel and stencil point the records' DTFT at the tones (Horner on the moments' Taylor terms), the Gram
matrix of the tones and their images (4 x 4 for two tones of a real ramp) from the Dirichlet kernel,
one linear solve and the energy J. numpy made a LAPACK call per tiny matrix behind a dozen passes of
assembly (``where``, ``concatenate``, ``einsum``, ``moveaxis``) over (P, S, M, M) temporaries: most of
the joint refinement's CPU. Here it is one pass. Not bit for bit: the sines and cosines are the C
library's (numpy's are its own vectorised ones) and the solve is Gaussian elimination with LAPACK's
partial pivoting (the largest |re| + |im|) in plain loops, so J agrees with the numpy path to
rounding (~1e-15 relative) and a refined frequency to ~1e-8 bin at most (a pixel whose last Newton
step sits at the convergence threshold may take one step more or less;
tests/dsp/spectrum/test_dsp_jit_fit.py). The numpy path is the reference and the fallback.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np

# error_model="numpy": a division by zero gives inf or NaN as in numpy (the callers replace those
# points), not Python's exception
_jit: Callable[[Callable[..., Any]], Any] = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def window_grid(den: np.ndarray, off: np.ndarray, fre: np.ndarray, fim: np.ndarray, cq: np.ndarray, sq: np.ndarray,
                num: np.ndarray, c: np.ndarray, s: np.ndarray, out: np.ndarray,
                near: np.ndarray) -> None:  # pragma: no cover (compiled; checked against numpy in the tests)
    """``out`` (B, R, Q) complex and ``near`` (B, R, Q): the cosine-sum window's DTFT on the grid of
    _window_dtft_grid from its numpy sines: ``den`` (B, R, J) the shifted kernels' denominators; per
    term t, ``off[t]`` its first column of ``den`` and ``fre[t]``, ``fim[t]`` its factors a_m (-1)^m
    cos(theta_m), a_m (-1)^m sin(theta_m); ``cq``, ``sq`` (Q,) the whole bins' sign and phase; ``num``,
    ``c``, ``s`` (B, R) the numerator's sine and the phase's cosine and sine. ``near``: a denominator
    under 1e-12 (the value there is inf or NaN, replaced by the caller)."""
    b_n, r_n, j_n = den.shape
    q_n = cq.size
    inv = np.empty(j_n)
    tiny = np.empty(j_n, dtype=np.bool_)
    for b in range(b_n):
        for r in range(r_n):
            for j in range(j_n):
                inv[j] = 1.0 / den[b, r, j]
                tiny[j] = abs(den[b, r, j]) < 1e-12
            cc = c[b, r]
            ss = s[b, r]
            nm = num[b, r]
            for q in range(q_n):
                s_re = 0.0
                s_im = 0.0
                hit = False
                for t in range(off.size):
                    s_re += fre[t] * inv[off[t] + q]
                    s_im -= fim[t] * inv[off[t] + q]
                    hit |= tiny[off[t] + q]
                t_re = cq[q] * s_re + sq[q] * s_im
                t_im = cq[q] * s_im - sq[q] * s_re
                o_re = cc * t_re
                o_re += ss * t_im
                o_im = cc * t_im
                o_im -= ss * t_re
                out[b, r, q] = complex(o_re * nm, o_im * nm)
                near[b, r, q] = hit


@_jit
def joint_stencil(gr: np.ndarray, gi: np.ndarray, live: np.ndarray, l_n: int, d: np.ndarray, offs: np.ndarray,
                  sidx: np.ndarray, cent: np.ndarray, active: np.ndarray, n: float, real: bool,
                  out: np.ndarray) -> bool:  # pragma: no cover (compiled; checked against numpy in the tests)
    """One iteration's J (m, S) of lidard.dsp.ranging.tones.refine_joint in one pass: for live pixel i
    (pixel ``live[i]`` of the moments) and stencil point s, tone t at cent + d + offs[sidx[s, t]] (the
    stencil's few distinct offsets ``offs``: each record's DTFT and each tone's own image term are taken
    once per offset, not once per stencil point); each record's DTFT from the Taylor coefficients
    ``gr``, ``gi`` (P, pairs; pair (pixel, record, tone) = (pixel L + record) K + tone) by Horner and
    the phase exp(-j pi delta (n-1)/n); G from the Dirichlet kernel; then J = sum_l b_l^H G^-1 b_l
    (:func:`_energy`). The sines and cosines are the C library's (numpy takes its own vectorised
    ones): J agrees with the numpy path to rounding. False: a singular G."""
    m_n, k = d.shape
    s_n = sidx.shape[0]
    u_n = offs.size
    p_terms = gr.shape[0]
    mm = 2 * k if real else k
    g = np.empty((mm, mm), dtype=np.complex128)
    y = np.empty((mm, l_n), dtype=np.complex128)
    rhs = np.empty((mm, l_n), dtype=np.complex128)
    on = np.empty(mm, dtype=np.bool_)
    fu = np.empty((u_n, k))
    xu = np.empty((u_n, l_n, k), dtype=np.complex128)
    own = np.empty((u_n, k), dtype=np.complex128)
    f = np.empty(k)
    for i in range(m_n):
        for t in range(mm):
            on[t] = active[i, t % k]
        for u in range(u_n):
            for t in range(k):
                delta = d[i, t] + offs[u]
                fu[u, t] = cent[i, t] + delta
                if real:        # D(2 f_t): a tone against its own image
                    own[u, t] = _dirichlet(fu[u, t] + fu[u, t], n)
                theta = -np.pi * delta * (n - 1.0) / n
                c = np.cos(theta)
                sn = np.sin(theta)
                for a in range(l_n):
                    col = (live[i] * l_n + a) * k + t
                    acc_re = 0.0
                    acc_im = 0.0
                    for p in range(p_terms - 1, -1, -1):
                        acc_re *= delta
                        acc_re += gr[p, col]
                        acc_im *= delta
                        acc_im += gi[p, col]
                    xu[u, a, t] = complex(c * acc_re - sn * acc_im, c * acc_im + sn * acc_re)
        for s in range(s_n):
            for t in range(k):
                u = sidx[s, t]
                f[t] = fu[u, t]
                for a in range(l_n):
                    rhs[t, a] = xu[u, a, t]
                    if real:
                        rhs[t + k, a] = np.conj(xu[u, a, t])
            # G_ij = D(f_i - f_j); for a real ramp the images' block is conj(A), A_ij = D(f_i - f_j) of the
            # tones, and the tones' against the images' is D(f_i + f_j), symmetric in i, j: K^2 kernels, not
            # K (2K - 1) (D(-x) = conj(D(x)))
            for r in range(k):
                for j in range(r + 1, k):
                    v = _dirichlet(f[r] - f[j], n)
                    g[r, j] = v
                    if real:
                        g[r + k, j + k] = np.conj(v)
                if real:
                    g[r, r + k] = own[sidx[s, r], r]
                    for j in range(r + 1, k):
                        v = _dirichlet(f[r] + f[j], n)
                        g[r, j + k] = v
                        g[j, r + k] = v
            e = _energy(g, rhs, on, n, y)
            if np.isnan(e) and _singular(g):
                return False
            out[i, s] = e
    return True


@_jit
def _dirichlet(x: float, n: float) -> complex:  # pragma: no cover
    """lidard.dsp.spectrum.windowdtft._dirichlet at one point (the C library's sines and cosines)."""
    a = np.pi * x
    den = np.sin(a / n)
    if abs(den) < 1e-12:
        ratio = n * np.cos(a) / np.cos(a / n)
    else:
        ratio = np.sin(a) / den
    b = a * (n - 1.0) / n
    return complex(np.cos(b) * ratio, -(np.sin(b) * ratio))


@_jit
def _energy(g: np.ndarray, rhs: np.ndarray, on: np.ndarray, n: float, y: np.ndarray) -> float:  # pragma: no cover
    """sum_l rhs_l^H G^-1 rhs_l with G's strict upper triangle given in ``g`` (Hermitian, diagonal ``n``)
    and the inactive tones' rows and columns the identity's, their rhs zero; ``g`` and ``y`` are
    overwritten. NaN on an exactly zero pivot (``g`` then holds the pivot's column: :func:`_singular`)."""
    m, l_n = rhs.shape
    for i in range(m):
        g[i, i] = n if on[i] else 1.0
        for j in range(i + 1, m):
            v = g[i, j] if (on[i] and on[j]) else 0j
            g[i, j] = v
            g[j, i] = np.conj(v)
        for a in range(l_n):
            if not on[i]:
                rhs[i, a] = 0j
            y[i, a] = rhs[i, a]
    if not _solve_in_place(g, y):
        g[0, 0] = 0j
        return np.nan
    acc = 0.0
    for i in range(m):
        for a in range(l_n):
            acc += y[i, a].real * rhs[i, a].real + y[i, a].imag * rhs[i, a].imag
    return acc


@_jit
def _singular(g: np.ndarray) -> bool:  # pragma: no cover
    """Whether :func:`_energy` stopped on a zero pivot (it marks g[0, 0] = 0: a G's diagonal never is)."""
    return g[0, 0] == 0


@_jit
def _solve_in_place(g: np.ndarray, y: np.ndarray) -> bool:  # pragma: no cover
    """G x = y by Gaussian elimination with partial pivoting (LAPACK's pivot: the largest |re| + |im|,
    the first of equals), x into ``y``; ``g`` is overwritten. False on an exactly zero pivot."""
    m = g.shape[0]
    cols = y.shape[1]
    for c in range(m):
        piv = c
        best = abs(g[c, c].real) + abs(g[c, c].imag)
        for r in range(c + 1, m):
            v = abs(g[r, c].real) + abs(g[r, c].imag)
            if v > best:
                best = v
                piv = r
        if best == 0.0:
            return False
        if piv != c:
            for j in range(m):
                t = g[c, j]
                g[c, j] = g[piv, j]
                g[piv, j] = t
            for j in range(cols):
                t = y[c, j]
                y[c, j] = y[piv, j]
                y[piv, j] = t
        d = g[c, c]
        for r in range(c + 1, m):
            f = g[r, c] / d
            if f != 0:
                for j in range(c + 1, m):
                    g[r, j] -= f * g[c, j]
                for j in range(cols):
                    y[r, j] -= f * y[c, j]
    for c in range(m - 1, -1, -1):
        for j in range(cols):
            acc = y[c, j]
            for i in range(c + 1, m):
                acc -= g[c, i] * y[i, j]
            y[c, j] = acc / g[c, c]
    return True



@_jit
def order_fit(x: np.ndarray, cols: np.ndarray, near: np.ndarray, white: np.ndarray, fit: np.ndarray,
              total: np.ndarray) -> bool:  # pragma: no cover (compiled; checked against numpy in the tests)
    """lidard.dsp.ranging.order.order_statistic's whitened least squares, one pass per detection: ``x``
    (Q, L, M) its cells in each record, ``cols`` (Q, L, K, M) the tones' window DTFT there (zero for
    the tones not ``near``, (Q, K)), ``white`` (M, M) the whitener. Into ``fit`` (Q,) the fitted
    energy summed over the records and ``total`` (Q,) the whitened cells' energy. False on an exactly
    zero pivot (the caller takes the numpy path, which says so)."""
    q_n, l_n, m = x.shape
    k = cols.shape[2]
    xw = np.empty(m, dtype=np.complex128)
    cw = np.empty((k, m), dtype=np.complex128)
    g = np.empty((k, k), dtype=np.complex128)
    rhs = np.empty(k, dtype=np.complex128)
    amp = np.empty((k, 1), dtype=np.complex128)
    for q in range(q_n):
        f_acc = 0.0
        t_acc = 0.0
        for a in range(l_n):
            for i in range(m):
                v = 0j
                for j in range(m):
                    v += white[i, j] * x[q, a, j]
                xw[i] = v
                t_acc += abs(v) ** 2
                for t in range(k):
                    v = 0j
                    for j in range(m):
                        v += white[i, j] * cols[q, a, t, j]
                    cw[t, i] = v
            _gram_rhs(cw, xw, near[q], g, rhs, 0.0)
            for t in range(k):
                amp[t, 0] = rhs[t]
            if not _solve_in_place(g, amp):
                return False
            for t in range(k):
                f_acc += (np.conj(rhs[t]) * amp[t, 0]).real
        fit[q] = f_acc
        total[q] = t_acc
    return True


@_jit
def residual_fit(x: np.ndarray, cols: np.ndarray, valid: np.ndarray, out: np.ndarray) -> bool:  # pragma: no cover
    """lidard.dsp.ranging.order.residual_near's fit and residual: ``x`` (P, L, M) the cells, ``cols``
    (P, L, K, M) the valid tones' window DTFT (zero for the others), ``valid`` (P, K). Each record's
    least-squares amplitudes (G regularised by 1e-12 of the largest |G| entry of the whole call, as
    there), and into ``out`` (P, M) the residual's power averaged over the records. False on an exactly
    zero pivot."""
    p_n, l_n, m = x.shape
    k = cols.shape[2]
    g = np.empty((k, k), dtype=np.complex128)
    rhs = np.empty(k, dtype=np.complex128)
    amp = np.empty((k, 1), dtype=np.complex128)
    gmax = 0.0
    for p in range(p_n):
        for a in range(l_n):
            _gram_rhs(cols[p, a], x[p, a], valid[p], g, rhs, 0.0)
            for t in range(k):
                for u in range(k):
                    if valid[p, t] and valid[p, u]:     # the others' entries are 0 before the identity
                        gmax = max(gmax, abs(g[t, u]))
    reg = 1e-12 * gmax
    for p in range(p_n):
        for i in range(m):
            out[p, i] = 0.0
        for a in range(l_n):
            _gram_rhs(cols[p, a], x[p, a], valid[p], g, rhs, reg)
            for t in range(k):
                amp[t, 0] = rhs[t]
            if not _solve_in_place(g, amp):
                return False
            for i in range(m):
                v = 0j
                for t in range(k):
                    v += amp[t, 0] * cols[p, a, t, i]
                r = x[p, a, i] - v
                out[p, i] += r.real * r.real + r.imag * r.imag
        for i in range(m):
            out[p, i] /= l_n
    return True


@_jit
def _gram_rhs(cw: np.ndarray, xw: np.ndarray, on: np.ndarray, g: np.ndarray, rhs: np.ndarray,
              reg: float) -> None:  # pragma: no cover
    """g = cw^H cw (K, K) with an absent tone's rows and columns the identity's, plus ``reg`` on the
    diagonal; rhs = cw^H xw."""
    k, m = cw.shape
    for t in range(k):
        v = 0j
        for i in range(m):
            v += np.conj(cw[t, i]) * xw[i]
        rhs[t] = v
        for u in range(k):
            if on[t] and on[u]:
                v = 0j
                for i in range(m):
                    v += np.conj(cw[t, i]) * cw[u, i]
            else:
                v = 1.0 + 0j if t == u else 0j
            g[t, u] = v + reg if t == u else v
