"""The compiled kernel of :mod:`sim_devices.world.synth_jit` (numba; imported by it on first use, only
if numba is installed). Its contract and the numpy code it stands in for are in synth_jit."""

from __future__ import annotations

import numba
import numpy as np


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
