"""The compiled kernel of :mod:`sim_devices.world.synth_jit` (numba; imported by it on first use, only
if numba is installed). Its contract and the numpy code it stands in for are in synth_jit."""

from __future__ import annotations

import numba
import numpy as np

from sim_devices.world import gauss


@numba.njit(cache=True, nogil=True)
def static_fill(c0, c1, c2, b_start, ratio, p, q, n, d_awg, neg_const, out):  # pragma: no cover (compiled)
    """:func:`sim_devices.world.synth_grid._fill` into ``out`` (n_hits, n).

    As the numpy path does, per residue j the hits are grouped by their integer offset delta from the
    record's grid: G and the delayed H1, H2 (strided gathers from the chirp tables, a cache line each
    at the large ratios of a decimated record) are built once per group, and each hit of the group
    costs four operations per sample on contiguous vectors. A scene's hits fall in a few groups (their
    delays differ by a few AWG samples), so the gathers are done a few times per batch, not per hit."""
    qn = min(q, n)
    nh = d_awg.size
    delta = np.empty(nh, np.int64)
    fh = np.empty(nh)
    length_max = (n + q - 1) // q
    g = np.empty(length_max)
    h1 = np.empty(length_max)
    h2 = np.empty(length_max)
    for j in range(qn):
        b = b_start + j * ratio
        ib = int(b)                          # b >= 0: truncation is floor
        fb = b - ib
        length = (n - j + q - 1) // q        # samples k = j + m q < n
        for h in range(nh):
            x = b - d_awg[h]
            ih = int(x)
            fh[h] = x - ih
            delta[h] = ib - ih
        order = np.argsort(delta)
        s = 0
        while s < nh:
            dv = delta[order[s]]
            e = s
            while e < nh and delta[order[e]] == dv:
                e += 1
            i0 = ib - dv
            for m in range(length):
                ia = ib + p * m
                ix = i0 + p * m
                gm = c0[ia] - c0[ix]
                gm += fb * (c1[ia] + fb * c2[ia])
                g[m] = gm
                h1[m] = c1[ix]
                h2[m] = c2[ix]
            for t in range(s, e):
                hh = order[t]
                f = fh[hh]
                nc = neg_const[hh]
                for m in range(length):
                    o = h2[m] * f
                    o += h1[m]
                    o *= f
                    o += nc
                    out[hh, j + m * q] = g[m] - o
            s = e


@numba.njit(cache=True, nogil=True)
def quantize_rows(v, noise, has_noise, scale, lo, hi, out, over):  # pragma: no cover (compiled)
    """:func:`sim_devices.world.synth_chunk.digitize_chunk`'s quantizer in one pass: per sample of the
    float32 ``v`` (rows, n), ``(v + noise) * scale`` rounded half to even, clipped to [lo, hi] into the
    int16 ``out``; ``over[r]``: a sample of row r was outside [lo, hi] before the clip. The float32
    operations of the numpy passes in their order (``scale``, ``lo``, ``hi`` are float32)."""
    rows, n = v.shape
    for r in range(rows):
        clipped = 0
        if has_noise:
            for k in range(n):
                x = np.rint((v[r, k] + noise[r, k]) * scale)
                y = min(max(x, lo), hi)          # branch-free: the loop vectorizes
                clipped += y != x
                out[r, k] = np.int16(y)
        else:
            for k in range(n):
                x = np.rint(v[r, k] * scale)
                y = min(max(x, lo), hi)
                clipped += y != x
                out[r, k] = np.int16(y)
        over[r] = clipped > 0


@numba.njit(cache=True, nogil=True)
def turns_to_radians_f32(turns, out):  # pragma: no cover (compiled)
    """:func:`sim_devices.world.synth_chunk.cos_sin`'s range reduction of a phase in cycles (1-D float64,
    |phase| < 2**24) into ``out`` (float32 radians in [-pi, pi]) in one pass: the whole cycles (exact),
    the fraction in float64, times 2 pi, rounded to float32 -- the numpy passes' operations."""
    two_pi = 2.0 * np.pi
    for i in range(turns.size):
        t = turns[i]
        out[i] = np.float32((t - np.rint(t)) * two_pi)


# -- the records' white noise (sim_devices.world.gauss: the same operations in the same order) ------------
_G = np.uint64(gauss.GAMMA)
_M1, _M2 = np.uint64(gauss.MIX1), np.uint64(gauss.MIX2)
_S11, _S27, _S30, _S31 = np.uint64(11), np.uint64(27), np.uint64(30), np.uint64(31)
_SA = np.uint64(64 - gauss.ANGLE_BITS)
_L0, _L1, _L2, _L3, _L4, _L5, _L6, _L7 = gauss.LOG_COEF
_C0, _C1, _C2, _C3, _C4, _C5, _C6 = gauss.COS_COEF
_N0, _N1, _N2, _N3, _N4, _N5 = gauss.SIN_COEF
_LN2, _SQRT2, _STEP = gauss.LN2, gauss.SQRT2, gauss.ANGLE_STEP
_HALF_Q = 1 << (gauss.ANGLE_BITS - 3)
_Q_SHIFT = gauss.ANGLE_BITS - 2
_MANT = 0x000FFFFFFFFFFFFF
_ONE = 0x3FF0000000000000


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _mix(c):  # pragma: no cover (compiled)
    z = (c ^ (c >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _noise_row(key, sd, h, w1, w2, f, e, noise):  # pragma: no cover (compiled)
    """gauss.normal_rows of one record into ``noise`` (float32, >= 2h): cosines at [0, h), sines at
    [h, 2h). Separate simple loops, each of which vectorizes (scratch w1, w2 uint64, f, e float64)."""
    g2 = _G + _G
    c = key + _G
    for j in range(h):                           # words 2j and 2j + 1
        w1[j] = _mix(c)
        w2[j] = _mix(c + _G)
        c += g2
    for j in range(h):                           # U (53 bits) as float64, exactly
        f[j] = np.float64(np.int64(w1[j] >> _S11) + 1)
    fb = f.view(np.int64)
    for j in range(h):                           # f = m 2**(e + 53), m in [1, 2): the bits
        b = fb[j]
        e[j] = np.float64((b >> 52) - 1076)
        fb[j] = (b & _MANT) | _ONE
    for j in range(h):
        m = f[j]
        ej = e[j]
        big = m > _SQRT2
        m = m * 0.5 if big else m
        ej = ej + 1.0 if big else ej
        s = (m - 1.0) / (m + 1.0)
        z = s * s
        p = _L0 * z + _L1
        p = p * z + _L2
        p = p * z + _L3
        p = p * z + _L4
        p = p * z + _L5
        p = p * z + _L6
        p = p * z + _L7
        lnu = ej * _LN2 + s * p
        f[j] = np.sqrt(lnu * -2.0) * sd
    for j in range(h):
        a = np.int64(w2[j] >> _SA)
        qq = (a + _HALF_Q) >> _Q_SHIFT
        t = a - (qq << _Q_SHIFT)
        q = qq & 3
        x = (np.float64(t) + 0.5) * _STEP
        z = x * x
        cs = _C0 * z + _C1
        cs = cs * z + _C2
        cs = cs * z + _C3
        cs = cs * z + _C4
        cs = cs * z + _C5
        cs = cs * z + _C6
        sn = _N0 * z + _N1
        sn = sn * z + _N2
        sn = sn * z + _N3
        sn = sn * z + _N4
        sn = sn * z + _N5
        sn = sn * x
        odd = (q & 1) == 1
        c1 = sn if odd else cs
        s1 = cs if odd else sn
        c1 = -c1 if (q == 1 or q == 2) else c1
        s1 = -s1 if q >= 2 else s1
        r = f[j]
        noise[j] = np.float32(r * c1)
        noise[j + h] = np.float32(r * s1)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def noise_rows(keys, std, out):  # pragma: no cover (compiled)
    """gauss.normal_rows(keys, n, std) into the float32 ``out`` (rows, n); ``std`` float64 per row."""
    rows, n = out.shape
    h = (n + 1) // 2
    w1 = np.empty(h, np.uint64)
    w2 = np.empty(h, np.uint64)
    f = np.empty(h)
    e = np.empty(h)
    noise = np.empty(2 * h, np.float32)
    for r in range(rows):
        _noise_row(keys[r], std[r], h, w1, w2, f, e, noise)
        for k in range(n):
            out[r, k] = noise[k]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def noisy_quantize_rows(v, keys, std, scale, lo, hi, out, over):  # pragma: no cover (compiled)
    """:func:`quantize_rows` with the noise of gauss.normal_rows(keys, n, std) drawn in the same pass,
    record by record (no noise array): the same float32 sum, scale, rounding, clip and flags. A row
    of ``std`` 0 has no noise (adding gauss' +-0 changes no code)."""
    rows, n = v.shape
    h = (n + 1) // 2
    w1 = np.empty(h, np.uint64)
    w2 = np.empty(h, np.uint64)
    f = np.empty(h)
    e = np.empty(h)
    noise = np.zeros(2 * h, np.float32)
    for r in range(rows):
        clipped = 0
        if std[r] != 0.0:
            _noise_row(keys[r], std[r], h, w1, w2, f, e, noise)
            for k in range(n):
                x = np.rint((v[r, k] + noise[k]) * scale)
                y = min(max(x, lo), hi)
                clipped += y != x
                out[r, k] = np.int16(y)
        else:
            for k in range(n):
                x = np.rint(v[r, k] * scale)
                y = min(max(x, lo), hi)
                clipped += y != x
                out[r, k] = np.int16(y)
        over[r] = clipped > 0
