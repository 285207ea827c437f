"""Joint maximum-likelihood refinement of the K tones of one ramp (dissertation §2.1, eq. 2-1).

Two surfaces a few range cells apart give two tones whose lobes overlap: a one-tone estimator
(:mod:`lidard.dsp.ranging.estimators`' ``newton``) refines each one as if it were alone, and the other's
leakage pulls it (about +0.1 bin, +2 mm, two returns four cells apart). The likelihood of a pixel's
ramps under the model "K tones in white Gaussian noise" has no such bias:

    x_a[t] = sum_k  c_ak exp(j w_k t)  [+ conj(c_ak) exp(-j w_k t) for a real ramp]  + noise,

with one complex amplitude per average ``a`` and tone (speckle, phase noise and the record's start
phase change them from record to record) and frequencies w_k common to the pixel's averages. With
the amplitudes fitted by least squares the log-likelihood of the frequencies is the energy of the
records in the span of the tones' columns (variable projection):

    J(w) = sum_a  b_a^H G(w)^-1 b_a,      b_a = E(w)^H x_a,   G = E^H E,

E the (N, K) or, real, (N, 2K) matrix of the complex exponentials. b_a holds the DTFT of the raw
(unwindowed) record at +-w_k (read from the moments of :class:`lidard.dsp.spectrum.dtft._DtftNearBin`: no
pass over the samples per step) and G the Dirichlet kernel at the pairwise differences, in closed
form. J is maximised by Newton steps on its finite-difference gradient and Hessian in all K
frequencies at once; a real ramp's negative-frequency images are part of the model, as in the
one-tone ``newton``. At K = 1 this is that estimator (averaged over the records by likelihood
instead of by the mean of the per-record estimates); it reaches the K-tone Cramer-Rao bound once
the tones are apart by more than about one bin (tests/dsp/ranging/test_dsp_ranging.py).

Pure numpy; where numba is installed one iteration's J on the stencil is one compiled pass.
"""

from __future__ import annotations

import numpy as np

from ..spectrum import jit
from ..spectrum.dtft import _DtftNearBin, _terms_for
from ..spectrum.windowdtft import _dirichlet

#: Newton iterations of the joint refinement (each a 3^K-point stencil of J; from a start within
#: ~0.2 bin it converges in two or three)
ITERATIONS = 4
#: the refinement moves each tone at most this far (bins) from its start: the one-tone estimates it
#: starts from are off by the other tone's leakage (~0.1 bin at two cells), never by a bin
REACH_BINS = 1.0
#: a pixel whose Newton step moves no tone by more than this (bins) has converged and leaves the
#: iterations (the next step would move it by about its square: ~1e-8 bin, far under any CRLB here)
CONVERGED_BINS = 1e-4
#: finite-difference step of J's derivatives (bins)
_H = 1e-3


def _stencil(k: int) -> np.ndarray:
    """(S, K) offsets in units of _H: centre, +-e_i, and +-e_i +-e_j (i < j): J's gradient and Hessian."""
    pts = [np.zeros(k)]
    for i in range(k):
        for s in (1.0, -1.0):
            e = np.zeros(k)
            e[i] = s
            pts.append(e)
    for i in range(k):
        for j in range(i + 1, k):
            for si in (1.0, -1.0):
                for sj in (1.0, -1.0):
                    e = np.zeros(k)
                    e[i], e[j] = si, sj
                    pts.append(e)
    return np.array(pts)


def _gram(f: np.ndarray, n: int) -> np.ndarray:
    """G_ij = D(f_i - f_j) of the tones ``f`` (..., M), D the Dirichlet kernel: Hermitian with n on the
    diagonal, so the kernel is evaluated on the pairs above it only (M (M - 1) / 2 of M^2)."""
    m = f.shape[-1]
    i, j = np.triu_indices(m, 1)
    upper = _dirichlet(f[..., i] - f[..., j], n)
    g = np.empty(f.shape + (m,), dtype=np.complex128)
    g[..., i, j] = upper
    g[..., j, i] = np.conj(upper)
    d = np.arange(m)
    g[..., d, d] = n
    return g


def joint_energy(b: np.ndarray, f: np.ndarray, active: np.ndarray, n: int, real: bool) -> np.ndarray:
    """J per pixel and stencil point: ``b`` (P, S, L, K) the records' DTFT at the tones, ``f`` (P, S, K)
    the tones (bins of the n-point grid), ``active`` (P, K) the tones in the model (an inactive tone's
    column is left out: unit diagonal, no projection)."""
    if real:   # columns exp(+j w t) then exp(-j w t); b for the latter is conj(X(f)) (x real)
        b = np.concatenate([b, np.conj(b)], axis=-1)
        f = np.concatenate([f, -f], axis=-1)
        active = np.concatenate([active, active], axis=-1)
    g = _gram(f, n)                                                      # (P, S, M, M)  G_ij = <e_i, e_j>
    on = active[:, None, :, None] & active[:, None, None, :]
    eye = np.eye(f.shape[-1], dtype=bool)
    g = np.where(on, g, np.where(eye, 1.0 + 0j, 0j))
    b = np.where(active[:, None, None, :], b, 0j)
    y = np.linalg.solve(g, np.swapaxes(b, -1, -2))                       # (P, S, M, L)
    return np.real(np.einsum("psml,pslm->ps", y, np.conj(b)))


def refine_joint(x: np.ndarray, f0: np.ndarray, active: np.ndarray, *, iterations: int = ITERATIONS,
                 reach: float = REACH_BINS) -> np.ndarray:
    """The K tones' frequencies (P, K), bins of the N-point grid, jointly refined from ``f0`` (P, K).

    ``x`` (P, L, N): each pixel's records (real, or complex for an I/Q receiver: then ``f0`` signed);
    ``active`` (P, K): which tones the model holds (the others are returned as given)."""
    x = np.asarray(x)
    p_n, l_n, n = x.shape
    k = f0.shape[-1]
    real = x.dtype.kind != "c"
    active = np.asarray(active, dtype=bool)
    if p_n == 0:
        return np.asarray(f0, dtype=np.float64).copy()
    start = np.where(active, np.asarray(f0, dtype=np.float64), 0.0)
    # DTFT moments around each (pixel, record, tone)'s start, reaching the search and the stencil
    rows = np.repeat(np.arange(p_n * l_n), k)
    centre = np.broadcast_to(np.rint(start)[:, None, :], (p_n, l_n, k)).reshape(-1)
    ev = _DtftNearBin(x.reshape(-1, n), rows, np.ascontiguousarray(centre, dtype=np.float64),
                      _terms_for(reach + 0.51 + 2 * _H))
    sten = _stencil(k) * _H                                              # (S, K)
    d = start - np.rint(start)                                           # (P, K) offset from the centres
    d0 = d.copy()
    cent = np.rint(start)
    live = np.arange(p_n)                                                # pixels still moving
    s_n = sten.shape[0]
    for _ in range(iterations):
        if live.size == 0:
            break
        m, act = live.size, active[live]
        j = _stencil_energy(ev, live, d[live], sten, cent[live], act, (l_n, n, real))
        if j is None:
            dd = d[live][:, None, :] + sten[None, :, :]                  # (m, S, K)
            # X(centre + dd) per record: the evaluator holds (P, L, K) pairs, offsets per stencil point
            delta = np.broadcast_to(dd[:, :, None, :], (m, s_n, l_n, k))
            cols = None if m == p_n else (live[:, None] * (l_n * k) + np.arange(l_n * k)).reshape(-1)
            xs = ev.dtft(np.moveaxis(delta, 1, 0).reshape(s_n, -1), cols=cols)   # (S, m*L*K)
            b = np.moveaxis(xs.reshape(s_n, m, l_n, k), 0, 1)              # (m, S, L, K)
            j = joint_energy(b, cent[live][:, None, :] + dd, act, n, real)
        step, newton = _newton_step(j, k, act)
        step = np.where(act, np.clip(step, -0.25, 0.25), 0.0)
        d[live] = np.clip(d[live] + step, d0[live] - reach, d0[live] + reach)
        # a Newton step this small has converged (the next moves by its square): the pixel is done
        live = live[~(newton & (np.abs(step).max(axis=1, initial=0.0) < CONVERGED_BINS))]
    return np.where(active, np.rint(start) + d, f0)


def _stencil_energy(ev: _DtftNearBin, live: np.ndarray, d: np.ndarray, sten: np.ndarray, cent: np.ndarray,
                    active: np.ndarray, dims: tuple[int, int, bool]) -> np.ndarray | None:
    """J (m, S) of the ``live`` pixels on the stencil by the compiled kernel (``dims``: the records per
    pixel, the ramp's samples and whether it is real; the records' DTFT, G and
    the solve in one pass: lidard.dsp.spectrum._kernels_fit.joint_stencil; J to rounding), or None
    (numba not loaded, or a singular G: the numpy path then)."""
    kern = jit.kernels(0)
    if kern is None:
        return None
    l_n, n, real = dims
    gr, gi = ev._terms()
    offs, sidx = np.unique(sten, return_inverse=True)       # the stencil's distinct offsets (0, +-_H)
    out = np.empty((live.size, sten.shape[0]))
    ok = kern.joint_stencil(gr, gi, np.ascontiguousarray(live, dtype=np.int64), int(l_n), np.ascontiguousarray(d),
                            offs, np.ascontiguousarray(sidx.reshape(sten.shape), dtype=np.int64),
                            np.ascontiguousarray(cent), np.ascontiguousarray(active), float(n), bool(real), out)
    return out if ok else None


def _newton_step(j: np.ndarray, k: int, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ascent step (P, K) from J on :func:`_stencil`'s points (P, S): Newton where the Hessian is
    negative definite, else a small step up the gradient (an inactive tone's row: a unit curvature of
    the active ones' scale, no step); and where it was Newton (P,)."""
    g = np.stack([(j[:, 1 + 2 * i] - j[:, 2 + 2 * i]) / (2 * _H) for i in range(k)], axis=-1)
    hess = np.zeros(j.shape[:1] + (k, k))
    for i in range(k):
        hess[:, i, i] = (j[:, 1 + 2 * i] + j[:, 2 + 2 * i] - 2 * j[:, 0]) / _H ** 2
    c = 1 + 2 * k
    for i in range(k):
        for m in range(i + 1, k):
            pp, pm, mp, mm = j[:, c], j[:, c + 1], j[:, c + 2], j[:, c + 3]
            hess[:, i, m] = hess[:, m, i] = (pp - pm - mp + mm) / (4 * _H ** 2)
            c += 4
    diag = np.diagonal(hess, axis1=1, axis2=2)
    scale = np.max(np.where(active, np.abs(diag), 0.0), axis=1, initial=0.0)
    off = ~active[:, :, None] | ~active[:, None, :]
    hess = np.where(off, 0.0, hess)
    idx = np.arange(k)
    hess[:, idx, idx] = np.where(active, diag, -np.maximum(scale, 1e-300)[:, None])
    g = np.where(active, g, 0.0)
    # scale-free test of definiteness: eigenvalues of -H all positive
    ev = np.linalg.eigvalsh(-hess)
    ok = ev[:, 0] > 1e-12 * np.maximum(np.abs(ev[:, -1]), 1e-300)
    safe = np.where(ok[:, None, None], hess, -np.eye(k)[None])
    newton = -np.linalg.solve(safe, g[..., None])[..., 0]
    # not concave here (a start off the lobe's top): a gradient step scaled by one tone's curvature
    # near its peak, -d2J/df2 ~ (2 pi)^2 / 12 J per bin^2 (a step of the right size on the flank)
    uphill = g / np.maximum((2 * np.pi) ** 2 / 12 * j[:, :1], 1e-300)
    return np.where(ok[:, None], newton, uphill), ok


def subtract_tones(x: np.ndarray, f: np.ndarray, active: np.ndarray) -> np.ndarray:
    """The records (P, L, N) less their least-squares fit by the tones ``f`` (P, K) (bins of the N-point
    grid; the inactive ones left out): what a further return, hidden under a peak, leaves."""
    x = np.asarray(x)
    n = x.shape[-1]
    real = x.dtype.kind != "c"
    t = np.arange(n)
    fa = np.where(active, f, 0.0)
    e = np.exp(2j * np.pi * fa[:, :, None] * t / n)                       # (P, K, N)
    cols = np.concatenate([e, np.conj(e)], axis=1) if real else e
    act = np.concatenate([active, active], axis=1) if real else active
    cols = np.where(act[:, :, None], cols, 0j)
    g = np.einsum("pkn,pmn->pkm", np.conj(cols), cols)
    g = np.where(act[:, :, None] & act[:, None, :], g, np.eye(cols.shape[1])[None])
    b = np.einsum("pkn,pln->pkl", np.conj(cols), x.astype(np.complex128))
    amp = np.linalg.solve(g, b)                                            # (P, M, L)
    fit = np.einsum("pkl,pkn->pln", amp, cols)
    return x - (fit.real if real else fit)
