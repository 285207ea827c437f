"""Optional compiled kernels of the detection chain (issue 18: "fused kernels are welcome, for example
with numba, if they stay optional"); the numpy code they replace stays the reference and the fallback.

Each kernel gives the same values, bit for bit, as the numpy code it stands in for (tested in
tests/dsp/test_dsp_jit.py): the same IEEE operations in the same order, no fast-math, and order
statistics are selections (the k-th smallest of a set is one of its elements whatever the method).
They exist because numpy makes one pass over the whole array per operation: the OS-CFAR screen of
:mod:`lidard.dsp.cfar_os` took about a dozen passes over every spectrum cell, here it is one.

numba is imported on first use, never at import time (``lidarctl --help`` and a scan's imports stay
fast, issue 18), and only if it is installed (``pip install lidard[fast]``); :func:`kernels` returns
None otherwise and the callers take their numpy path. ``LIDARD_DSP_JIT=0`` in the environment turns
the kernels off (for comparing the two paths; the results do not depend on it).
"""

from __future__ import annotations

import os
from functools import lru_cache
from types import SimpleNamespace

import numpy as np


@lru_cache(maxsize=1)
def _compiled() -> SimpleNamespace | None:
    try:
        import numba
    except ImportError:
        return None
    jit = numba.njit(cache=True, nogil=True)
    return SimpleNamespace(os_screen=jit(_os_screen), power=jit(_power))


def kernels() -> SimpleNamespace | None:
    """The compiled kernels, or None (numba missing, or LIDARD_DSP_JIT=0)."""
    if os.environ.get("LIDARD_DSP_JIT", "1") == "0":
        return None
    return _compiled()


def power(spec: np.ndarray) -> np.ndarray:
    """|X|^2 = re^2 + im^2 of a complex spectrum (float64), one pass (numpy: three)."""
    k = kernels()
    s = np.asarray(spec)
    if k is None or s.dtype != np.complex128 or s.size == 0:
        return s.real ** 2 + s.imag ** 2
    out = np.empty(s.shape)
    k.power(np.ascontiguousarray(s).reshape(-1), out.reshape(-1))
    return out


def os_screen(p: np.ndarray, n_ref_side: int, n_guard: int, k_rank: int, thr_factor: float, mean_kth: float,
              kern: SimpleNamespace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, bins, noise) of the local maxima of ``p`` (rows, n) that may pass OS-CFAR, with the
    exact statistic (k-th smallest of the reference cells, mirrored at the edges, / ``mean_kth``).

    A local maximum c is kept when at least ``k_rank`` of its reference cells lie below
    p[c] * ``thr_factor`` (a necessary condition of the detector's test, see cfar_os._os_screened)."""
    p = np.ascontiguousarray(p, dtype=np.float64)
    cap = max(1024, 4 * p.shape[0])
    while True:
        r = np.empty(cap, np.int64)
        c = np.empty(cap, np.int64)
        noise = np.empty(cap)
        m = kern.os_screen(p, n_ref_side, n_guard, k_rank, thr_factor, mean_kth, r, c, noise)
        if m >= 0:
            return r[:m], c[:m], noise[:m]
        cap *= 4    # more cells than room: again with more (rare: a spectrum full of strong peaks)


def _power(z, out):   # pragma: no cover (compiled; its twin is checked against numpy in the tests)
    for i in range(z.size):
        out[i] = z[i].real * z[i].real + z[i].imag * z[i].imag


def _os_screen(p, n_side, guard, k, thr_factor, mean_kth, out_r, out_c, out_noise):  # pragma: no cover
    rows, n = p.shape
    n_ref = 2 * n_side
    reach = guard + n_side
    lim = n_ref - k             # more reference cells than this at or above the threshold: no detection
    ref = np.empty(n_ref)
    idx = np.empty(n_ref, np.int64)
    maxima = np.empty(n, np.int64)
    m = 0
    for r in range(rows):
        row = p[r]
        # the local maxima of the row (beyond either edge is -inf), listed without a branch per cell
        q = 0
        if row[0] > row[1]:
            maxima[q] = 0
            q += 1
        for c in range(1, n - 1):
            maxima[q] = c
            q += (row[c] >= row[c - 1]) & (row[c] > row[c + 1])
        if row[n - 1] >= row[n - 2]:
            maxima[q] = n - 1
            q += 1
        for e in range(q):
            c = maxima[e]
            t = row[c] * thr_factor
            above = 0
            if reach <= c < n - reach:  # inside: two contiguous runs of reference cells
                for j in range(c - reach, c - guard):
                    above += row[j] >= t
                for j in range(c + guard + 1, c + reach + 1):
                    above += row[j] >= t
                if above > lim:
                    continue
            for i in range(n_ref):      # reference cells: offsets -reach..-guard-1, guard+1..reach
                j = c - reach + i if i < n_side else c + guard + 1 + (i - n_side)
                idx[i] = -j if j < 0 else (2 * (n - 1) - j if j >= n else j)     # mirrored at the edges
            if not reach <= c < n - reach:
                for i in range(n_ref):
                    above += row[idx[i]] >= t
                if above > lim:
                    continue
            if m >= out_r.size:
                return -1
            for i in range(n_ref):
                ref[i] = row[idx[i]]
            ref.sort()
            out_r[m] = r
            out_c[m] = c
            out_noise[m] = ref[k - 1] / mean_kth
            m += 1
    return m
