"""The compiled kernels of :mod:`lidard.dsp.spectrum.jit` (numba; imported by it on first use, only if numba is
installed: importing this module compiles nothing but needs numba). The callers and the contract of
each kernel are in :mod:`lidard.dsp.spectrum.jit`; the numpy code each one stands in for is the reference
(tests/dsp/spectrum/test_dsp_jit.py, tests/dsp/detect/test_dsp_os_screens.py compare them bit for bit).

OS-CFAR (§2.4's detection at a chosen false-alarm rate): a cell c passes when its power is
above alpha times the k-th smallest of its reference cells. That needs at least k reference cells below
p[c] / alpha (``thr_factor`` adds a margin of 1e-9 for the rounding of the final test), so a cell that
fails this count cannot pass. :func:`os_scan` applies the count first to a whole block of
``OS_BLOCK`` cells at once, with the block's largest cell and the block's neighbourhood (a superset of
every window of the block): a necessary condition that most blocks of noise fail in about
(OS_BLOCK + 2 reach) / OS_BLOCK compares per cell, where the per-cell count costs n_ref per local
maximum. Only the local maxima of the blocks left are counted, and only those passing get the exact
order statistic. Edges are mirrored (numpy's "reflect"), as in :func:`lidard.dsp.detect.os_cfar._mirror_padded`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np

# numba carries no type information: the compiled functions are typed Any to their (few) callers
_jit: Callable[[Callable[..., Any]], Any] = numba.njit(cache=True, nogil=True)

OS_BLOCK = 16       # cells per block of the OS-CFAR screen
_HOOD = 48          # block neighbourhoods up to this many cells are counted in one fixed-length loop
_INF_BITS = 0x7FF0000000000000     # bit patterns of non-negative finite doubles (not -0.0) are below this


@_jit
def power(z: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover (compiled; checked against numpy in the tests)
    for i in range(z.size):
        out[i] = z[i].real * z[i].real + z[i].imag * z[i].imag


@_jit
def _block_tops(row: np.ndarray, bits: np.ndarray, top: np.ndarray, buf: np.ndarray,
                reach: int) -> tuple[float, bool]:  # pragma: no cover
    """Largest cell of each block of ``row`` into ``top``, and the row into buf[reach:] (the same
    pass over memory); returns (row max, plain): plain when every cell is a non-negative finite
    number and not -0.0, read from the int64 bit patterns ``bits`` (whose order is then the cells'
    order; the max and min of integers vectorise)."""
    n = row.size
    low = bits[0]
    high = bits[0]
    inner = buf[reach:reach + n]
    for j in range(n):
        x = bits[j]
        inner[j] = row[j]
        low = min(low, x)
        high = max(high, x)
    full = n // OS_BLOCK
    for b in range(full):
        blk = row[b * OS_BLOCK:b * OS_BLOCK + OS_BLOCK]     # a slice: see _count_below
        t0, t1, t2, t3 = blk[0], blk[1], blk[2], blk[3]     # four chains: not one max after another
        for j in range(4, OS_BLOCK, 4):
            t0, t1 = max(t0, blk[j]), max(t1, blk[j + 1])
            t2, t3 = max(t2, blk[j + 2]), max(t3, blk[j + 3])
        top[b] = max(max(t0, t1), max(t2, t3))
    if full < top.size:
        t = row[full * OS_BLOCK]
        for x in row[full * OS_BLOCK:]:
            t = max(t, x)
        top[full] = t
    if low >= 0 and high < _INF_BITS:
        return np.int64(high).view(np.float64), True
    row_max = top[0]
    for t in top:
        row_max = max(row_max, t)
    return row_max, False


@_jit
def _has_bad(row: np.ndarray) -> bool:  # pragma: no cover
    bad = False
    for x in row:
        bad |= not ((x >= 0.0) & (x <= 1.7976931348623157e308))      # NaN, negative or infinite
    return bad


@_jit
def _fill_mirrored(row: np.ndarray, reach: int, buf: np.ndarray) -> None:  # pragma: no cover
    """The ``reach`` mirrored cells on each side of buf[reach + j] = row[j] (the edge cell not repeated)."""
    n = row.size
    for i in range(reach):
        buf[i] = row[reach - i]
        buf[reach + n + i] = row[n - 2 - i]


@_jit
def _count_below(buf: np.ndarray, lo: int, length: int, t: float) -> int:  # pragma: no cover
    """How many of buf[lo : lo + length] are not >= t (NaN counts, as in the per-cell count)."""
    below = 0
    for s in range(0, length, _HOOD):   # fixed-length masked chunks: vectorised (buf has _HOOD spare cells)
        seg = buf[lo + s:lo + s + _HOOD]    # a slice: indices from 0 need no negative-index wrap (no gathers)
        rest = length - s
        for j in range(_HOOD):
            below += (not seg[j] >= t) & (j < rest)
    return below


@_jit
def _kth(ref: np.ndarray, k: int, plain: bool) -> float:  # pragma: no cover
    """The k-th smallest of ``ref`` (as ``np.sort(ref)[k - 1]``: the same element, NaN last)."""
    if not plain:
        ref.sort()
        return ref[k - 1]
    kth = ref[0]
    for i in range(ref.size):       # the element with k - 1 before it in (value, position) order
        v = ref[i]
        rank = 0
        for j in range(ref.size):
            rank += (ref[j] < v) | ((ref[j] == v) & (j < i))
        if rank == k - 1:
            kth = v
    return kth


@_jit
def _local_maxima(buf: np.ndarray, reach: int, lo: int, hi: int, n: int, maxima: np.ndarray) -> int:  # pragma: no cover
    """The local maxima among cells lo..hi-1 into ``maxima`` (beyond either edge is -inf); returns
    their number. Listed without a branch per cell; the mirrored cell at the first edge gives the
    edge's own test (x > p[1]), the last cell is tested apart (x >= p[n - 2])."""
    q = 0
    last = hi if hi < n else n - 1
    seg = buf[reach + lo - 1:reach + last + 1]
    for i in range(last - lo):
        x = seg[i + 1]
        maxima[q] = lo + i
        q += (x >= seg[i]) & (x > seg[i + 2])
    if hi == n:
        maxima[q] = n - 1
        q += buf[reach + n - 1] >= buf[reach + n - 2]
    return q


@_jit
def _pass_cells(r: int, buf: np.ndarray, q: int, maxima: np.ndarray, plain: bool, floor: float,
                cfg: tuple[int, int, int, float, float, float, bool], out_r: np.ndarray, out_c: np.ndarray,
                out_noise: np.ndarray, m: int) -> int:  # pragma: no cover
    """The per-cell count, then the exact statistic, for the local maxima listed; appends the cells
    kept (all that pass the count, or with ``exact`` those that pass the detector's test) at ``m``;
    returns the new count, or -1 when the output is full."""
    n_side, guard, k, thr_factor, mean_kth, scaled_alpha, exact = cfg
    reach = guard + n_side
    lim = 2 * n_side - k            # more reference cells than this at or above the threshold: no detection
    ref = np.empty(2 * n_side)
    for e in range(q):
        c = maxima[e]
        before = buf[c:c + n_side]                              # reference cells: offsets -reach..-guard-1
        after = buf[c + reach + guard + 1:c + 2 * reach + 1]    # and guard+1..reach
        x = buf[reach + c]
        t = x * thr_factor
        above = 0
        for i in range(n_side):
            above += (before[i] >= t) + (after[i] >= t)
        if above > lim:
            continue
        for i in range(n_side):
            ref[i] = before[i]
            ref[n_side + i] = after[i]
        noise = _kth(ref, k, plain) / mean_kth
        if exact and not (x > scaled_alpha * noise and noise > 0 and x > floor):
            continue
        if m >= out_r.size:
            return -1
        out_r[m] = r
        out_c[m] = c
        out_noise[m] = noise
        m += 1
    return m


@_jit
def os_scan(p: np.ndarray, bits: np.ndarray, n_side: int, guard: int, k: int, thr_factor: float, mean_kth: float,
            scaled_alpha: float, floor_factor: float, exact: bool, out_r: np.ndarray, out_c: np.ndarray,
            out_noise: np.ndarray) -> int:  # pragma: no cover
    """OS-CFAR over the rows of ``p`` (``bits``: the same memory as int64), see :func:`lidard.dsp.spectrum.jit.os_detect`
    (``exact``) and :func:`lidard.dsp.spectrum.jit.os_screen`. Returns the number of cells written, -1 if
    they do not fit, -2 (``exact`` only) if ``p`` holds a NaN, an infinite or a negative value."""
    rows, n = p.shape
    reach = guard + n_side
    n_blocks = (n + OS_BLOCK - 1) // OS_BLOCK
    buf = np.zeros(n_blocks * OS_BLOCK + 2 * reach + _HOOD)    # row r mirrored: buf[reach + j] = p[r, j]
    top = np.empty(n_blocks)
    maxima = np.empty(OS_BLOCK, np.int64)
    cfg = (n_side, guard, k, thr_factor, mean_kth, scaled_alpha, exact)
    m = 0
    for r in range(rows):
        row = p[r]
        row_max, plain = _block_tops(row, bits[r], top, buf, reach)
        if exact and not plain and _has_bad(row):
            return -2
        _fill_mirrored(row, reach, buf)
        floor = floor_factor * row_max
        for b in range(n_blocks):
            if exact and not top[b] > floor:
                continue            # no cell of the block passes the dynamic-range floor
            lo = b * OS_BLOCK
            hi = min(lo + OS_BLOCK, n)
            if _count_below(buf, lo, hi - lo + 2 * reach, top[b] * thr_factor) < k:
                continue            # no cell of the block can have k reference cells below its threshold
            q = _local_maxima(buf, reach, lo, hi, n, maxima)
            m = _pass_cells(r, buf, q, maxima, plain, floor, cfg, out_r, out_c, out_noise, m)
            if m < 0:
                return -1
    return m


@_jit
def widths_6db(flat: np.ndarray, start: np.ndarray, col: np.ndarray, n: int, max_half: int,
               out: np.ndarray) -> None:  # pragma: no cover
    """-6 dB full widths of the peaks at flat[start + col] (rows of ``n`` cells from ``start``), as
    lidard.dsp.detect._post._widths_flat computes them: per side the first of ``max_half`` cells out
    (the edge cell repeating) below a quarter of the peak, interpolated with the cell before it."""
    for i in range(col.size):
        peak = flat[start[i] + col[i]]
        level = peak / 4.0
        width = 0.0
        for direction in (-1, 1):
            half = float(max_half)
            prev = peak
            for s in range(max_half):
                j = min(max(col[i] + direction * (s + 1), 0), n - 1)
                v = flat[start[i] + j]
                if v < level:
                    frac = (prev - level) / (prev - v) if prev > v else 0.0
                    half = s + frac
                    break
                prev = v
            width += half
        out[i] = width


@_jit
def bin_table(tw: np.ndarray, basis: np.ndarray, k: int, out: np.ndarray) -> None:  # pragma: no cover
    """lidard.dsp.spectrum.dtft._moments_on_bins's table of bin ``k``: out[t, c, q] = tw[(k t) mod n, c] * basis[t, q]
    (the demodulated Chebyshev basis, cos and sin parts), the same products without the gathered copy."""
    n, q_terms = basis.shape
    for t in range(n):
        j = (k * t) % n
        c = tw[j, 0]
        s = tw[j, 1]
        for q in range(q_terms):
            out[t, 0, q] = c * basis[t, q]
            out[t, 1, q] = s * basis[t, q]


@_jit
def _safe_div(num: float, den: float) -> float:  # pragma: no cover
    return num / den if abs(den) > 0 else 0.0


@_jit
def newton_real_step(gr: np.ndarray, gi: np.ndarray, d: np.ndarray, d0: np.ndarray, offsets: np.ndarray,
                     cos_phi: np.ndarray, sin_phi: np.ndarray, cos_w: np.ndarray, sin_w: np.ndarray,
                     cos_w1: np.ndarray, sin_w1: np.ndarray, turn: np.ndarray, n: int, det_floor: float,
                     reach: float, h2: float, hh: float) -> None:  # pragma: no cover
    """One Newton step of lidard.dsp.ranging.estimators._est_newton on real ramps, in place on ``d`` (m,):
    the real-tone likelihood at d + each of the three ``offsets`` (_real_tone_fit: Horner on the Taylor
    coefficients gr, gi (P, m), the turned angles, the two-column least squares), its finite-difference
    derivatives and the clipped step; the same IEEE operations in the same order as numpy. The
    transcendentals come from numpy (its own vectorised cos and sin): ``cos_phi`` ... ``sin_w1`` (m,) of
    the angles pi d (n-1)/n, w = 2 pi (f0 + d)/n and w (n-1); ``turn`` (6, 3): cos and sin of the
    offsets' angles pi o (n-1)/n, 2 pi o/n and 2 pi o (n-1)/n."""
    m = gr.shape[1]
    nf = float(n)
    j = np.empty(3)
    delta = np.empty((3, _STEP_BLOCK))
    acc_re = np.empty((3, _STEP_BLOCK))
    acc_im = np.empty((3, _STEP_BLOCK))
    for i0 in range(0, m, _STEP_BLOCK):
        nb = min(_STEP_BLOCK, m - i0)
        _horner3(gr, gi, d, offsets, i0, nb, delta, acc_re, acc_im)
        for b in range(nb):
            _newton_pair(i0 + b, acc_re[:, b], acc_im[:, b], j, d, d0, cos_phi, sin_phi, cos_w, sin_w, cos_w1,
                         sin_w1, turn, nf, det_floor, reach, h2, hh)


@_jit
def _horner3(gr: np.ndarray, gi: np.ndarray, d: np.ndarray, offsets: np.ndarray, i0: int, nb: int, delta: np.ndarray,
             acc_re: np.ndarray, acc_im: np.ndarray) -> None:  # pragma: no cover
    """G at d + each of the three offsets for the block of pairs [i0, i0 + nb): Horner over the terms
    (term-major: rows of gr), a block at a time (each term's row read once)."""
    p_terms = gr.shape[0]
    for r in range(3):
        for b in range(nb):
            delta[r, b] = d[i0 + b] + offsets[r]
            acc_re[r, b] = 0.0
            acc_im[r, b] = 0.0
    for p in range(p_terms - 1, -1, -1):
        for b in range(nb):
            g_re = gr[p, i0 + b]
            g_im = gi[p, i0 + b]
            for r in range(3):
                acc_re[r, b] = acc_re[r, b] * delta[r, b] + g_re
                acc_im[r, b] = acc_im[r, b] * delta[r, b] + g_im


@_jit
def real_slopes(gr: np.ndarray, gi: np.ndarray, d: np.ndarray, offsets: np.ndarray, cos_phi: np.ndarray,
                sin_phi: np.ndarray, cos_w: np.ndarray, sin_w: np.ndarray, cos_w1: np.ndarray, sin_w1: np.ndarray,
                turn: np.ndarray, n: int, det_floor: float, h2: float, hh: float, energy: np.ndarray, slope: np.ndarray,
                curv: np.ndarray) -> None:  # pragma: no cover
    """The real-tone likelihood, its finite-difference slope and curvature (m,) at ``d`` (m,), the same
    evaluation as newton_real_step's without its step (its arguments alike): for the pixel fit
    (lidard.dsp.ranging.pixeltone), which sums them over a pixel's records before it steps."""
    m = gr.shape[1]
    nf = float(n)
    j = np.empty(3)
    delta = np.empty((3, _STEP_BLOCK))
    acc_re = np.empty((3, _STEP_BLOCK))
    acc_im = np.empty((3, _STEP_BLOCK))
    for i0 in range(0, m, _STEP_BLOCK):
        nb = min(_STEP_BLOCK, m - i0)
        _horner3(gr, gi, d, offsets, i0, nb, delta, acc_re, acc_im)
        for b in range(nb):
            i = i0 + b
            _pair_energies(i, acc_re[:, b], acc_im[:, b], j, cos_phi, sin_phi, cos_w, sin_w, cos_w1, sin_w1, turn,
                           nf, det_floor)
            energy[i] = j[1]
            slope[i] = (j[2] - j[0]) / h2
            curv[i] = (j[2] - 2.0 * j[1] + j[0]) / hh


#: pairs per block of newton_real_step's Horner pass: the block's accumulators (6 x 64 doubles) stay in L1 while
#: the pass reads each term's row of coefficients once (a cache-blocking size, not a model parameter)
_STEP_BLOCK = 64


@_jit
def _newton_pair(i: int, a_res: np.ndarray, a_ims: np.ndarray, j: np.ndarray, d: np.ndarray, d0: np.ndarray,
                 cos_phi: np.ndarray, sin_phi: np.ndarray, cos_w: np.ndarray, sin_w: np.ndarray, cos_w1: np.ndarray,
                 sin_w1: np.ndarray, turn: np.ndarray, nf: float, det_floor: float, reach: float, h2: float,
                 hh: float) -> None:  # pragma: no cover
    """The rest of newton_real_step for pair ``i``, from G at its three offsets (a_res, a_ims)."""
    di = d[i]
    _pair_energies(i, a_res, a_ims, j, cos_phi, sin_phi, cos_w, sin_w, cos_w1, sin_w1, turn, nf, det_floor)
    dp = (j[2] - j[0]) / h2
    dpp = (j[2] - 2.0 * j[1] + j[0]) / hh
    if dpp < 0:
        step = -_safe_div(dp, dpp)
    elif dp > 0:
        step = 0.05
    elif dp < 0:
        step = -0.05
    elif dp == 0:
        step = 0.0
    else:
        step = np.nan
    if step < -0.25:
        step = -0.25
    elif step > 0.25:
        step = 0.25
    v = di + step
    lo = d0[i] - reach
    hi = d0[i] + reach
    if v < lo:
        v = lo
    elif v > hi:
        v = hi
    d[i] = v


@_jit
def _pair_energies(i: int, a_res: np.ndarray, a_ims: np.ndarray, j: np.ndarray, cos_phi: np.ndarray,
                   sin_phi: np.ndarray, cos_w: np.ndarray, sin_w: np.ndarray, cos_w1: np.ndarray, sin_w1: np.ndarray,
                   turn: np.ndarray, nf: float, det_floor: float) -> None:  # pragma: no cover
    """j[r]: the real-tone least-squares energy of pair ``i`` at its three offsets (_real_tone_fit),
    from G there (a_res, a_ims) and the turned angles."""
    for r in range(3):
        a_re = a_res[r]
        a_im = a_ims[r]
        cp = cos_phi[i] * turn[0, r] - sin_phi[i] * turn[1, r]
        sp = sin_phi[i] * turn[0, r] + cos_phi[i] * turn[1, r]
        c = cp * a_re + sp * a_im
        s = sp * a_re - cp * a_im
        cw = cos_w[i] * turn[2, r] - sin_w[i] * turn[3, r]
        sw = sin_w[i] * turn[2, r] + cos_w[i] * turn[3, r]
        cos_n1 = cos_w1[i] * turn[4, r] - sin_w1[i] * turn[5, r]
        sin_n1 = sin_w1[i] * turn[4, r] + cos_w1[i] * turn[5, r]
        sin_nw = sin_n1 * cw + cos_n1 * sw
        if abs(sw) < 1e-12:
            dirichlet = nf * cos_n1
        else:
            dirichlet = sin_nw / sw
        scc = 0.5 * (nf + cos_n1 * dirichlet)
        sss = 0.5 * (nf - cos_n1 * dirichlet)
        scs = 0.5 * sin_n1 * dirichlet
        det = scc * sss - scs * scs
        if det > det_floor:
            j[r] = _safe_div(sss * c * c - 2.0 * scs * c * s + scc * s * s, det)
        else:
            j[r] = _safe_div(c * c, scc)
