"""The compiled kernel of :mod:`sim_devices.world.synth_jit` (numba; imported by it on first use, only
if numba is installed). Its contract and the numpy code it stands in for are in synth_jit."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def static_fill(c0, c1, c2, b_start, ratio, p, q, n, d_awg, neg_const, out):  # pragma: no cover (compiled)
    """:func:`sim_devices.world.synth_grid._fill` into ``out`` (n_hits, n), hit by hit in sample order."""
    qn = min(q, n)
    ib = np.empty(qn, np.int64)
    fb = np.empty(qn)
    ih = np.empty(qn, np.int64)
    fh = np.empty(qn)
    for j in range(qn):
        b = b_start + j * ratio
        ib[j] = int(b)                       # b >= 0: truncation is floor
        fb[j] = b - ib[j]
    for h in range(d_awg.size):
        for j in range(qn):
            x = (b_start + j * ratio) - d_awg[h]
            ih[j] = int(x)
            fh[j] = x - ih[j]
        nc = neg_const[h]
        for m in range((n + q - 1) // q):          # sample k = m q + j: residue j, step m
            for j in range(min(q, n - m * q)):
                ia = ib[j] + p * m
                ix = ih[j] + p * m
                f = fh[j]
                g = c0[ia] - c0[ix]
                g += fb[j] * (c1[ia] + fb[j] * c2[ia])
                o = c2[ix] * f
                o += c1[ix]
                o *= f
                o += nc
                out[h, m * q + j] = g - o
