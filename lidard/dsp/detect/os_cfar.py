"""OS-CFAR's noise statistic, split from :mod:`lidard.dsp.detect.cfar` (which re-exports these names).

Ordered statistic (Rohling 1983): the noise of a cell is the k-th smallest of its N reference cells;
alpha solves Pfa = prod_{i=0}^{k-1} (N - i) / (N - i + alpha) for exponential noise (§2.4: detection
at a chosen false-alarm rate). On a spectrum averaged over K records each noise cell is Gamma(K), not
exponential, and both alpha and the noise-mean scale come from that model (:mod:`.os_gamma`; K = 1 is
Rohling's closed form, used as is). The detector computes the statistic exactly only at the local maxima
that could pass the threshold (:func:`_os_screened`: screens that are necessary conditions of
the exact test, so the detections are the exact statistic's); :func:`_noise_os` gives the statistic at
every bin (exactly, or a lower bound where nothing can pass). Pure numpy;
:func:`_os_detected`, the detector's entry, takes the compiled pass instead when numba is installed
(:mod:`lidard.dsp.spectrum.jit`: the same cells, bit for bit, with the value check and the threshold test in it).
"""

from __future__ import annotations

from functools import lru_cache
from types import SimpleNamespace

import numpy as np

from lidard.dsp.detect.os_gamma import os_gamma_mean_kth, os_gamma_pfa
from lidard.dsp.spectrum import jit
from lidard.dsp.spectrum.window import DspInputError


def os_cfar_pfa(alpha: float, n_ref: int, k: int, records: int = 1) -> float:
    """Exact Pfa of OS-CFAR (k-th of N cells) for threshold factor alpha, each cell the mean power of
    ``records`` records (1: exponential noise, Rohling's product; more: :func:`.os_gamma.os_gamma_pfa`)."""
    if records == 1:
        i = np.arange(k)
        return float(np.prod((n_ref - i) / (n_ref - i + alpha)))
    return os_gamma_pfa(alpha, n_ref, k, records)


@lru_cache(maxsize=256)
def os_cfar_alpha(n_ref: int, k: int, pfa: float, records: int = 1) -> float:
    """OS-CFAR threshold factor solving os_cfar_pfa(alpha, records=records) = pfa (bisection, cached)."""
    _check_pfa(pfa)
    if not 1 <= k <= n_ref:
        raise DspInputError(f"OS-CFAR rank k={k} must lie in 1..n_ref={n_ref}")
    _check_records(records)
    lo, hi = 0.0, 1.0
    while os_cfar_pfa(hi, n_ref, k, records) > pfa:
        lo, hi = hi, hi * 2.0
    # Pfa falls monotonically with alpha: bisect to a relative 1e-13 (not scipy.optimize: importing it
    # costs ~0.4 s of every scan's start-up)
    while hi - lo > 1e-13 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if os_cfar_pfa(mid, n_ref, k, records) > pfa else (lo, mid)
    return 0.5 * (lo + hi)


def _check_records(records: int) -> None:
    if isinstance(records, bool) or not isinstance(records, (int, np.integer)) or records < 1:
        raise DspInputError(f"records={records!r} (the records averaged into each cell) must be an integer >= 1")


def _check_pfa(pfa: float) -> None:
    if not (0.0 < pfa < 1.0):
        raise DspInputError(f"pfa={pfa!r} must lie strictly between 0 and 1")


def _noise_os(p: np.ndarray, n_ref_side: int, n_guard: int, pfa: float, rank: int | None,
              exact: bool = False, records: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """OS-CFAR noise per bin, exact wherever the threshold test can pass.

    The k-th smallest of a set is never below the k-th smallest of a superset, so the k-th smallest
    of a block's whole neighbourhood (``_OS_BLOCK`` bins plus their reach on both sides, the cell
    under test and guards included) bounds every reference window of the block from below. A bin
    whose power is under alpha times that bound cannot pass the exact test; only the others get the
    exact order statistic (in white noise ~1e-4 of the bins, plus the targets). The detections are
    the same as with the exact statistic at every bin; the noise reported for a bin that was not
    computed exactly is its lower bound (only detections' noise is used downstream); ``exact=True``
    computes every bin exactly (a spectrum view that draws the threshold). The detector itself uses
    :func:`_os_screened` (the same decisions without a dense noise array). ``records``: the records
    averaged into each cell of ``p`` (the noise model's K)."""
    reach = n_guard + n_ref_side
    lead = p.shape[:-1]
    p = p.reshape(-1, p.shape[-1])
    rows, n = p.shape
    if n <= reach:
        raise DspInputError(f"spectrum of {n} bins is too short for OS-CFAR reach {reach}")
    k, mean_kth, scaled_alpha, _ = _os_constants(n_ref_side, pfa, rank, records)
    n_blocks = -(-n // _OS_BLOCK)
    pp = _mirror_padded(p, reach, n_blocks * _OS_BLOCK - n + reach)
    hood = np.lib.stride_tricks.as_strided(
        pp, (rows, n_blocks, _OS_BLOCK + 2 * reach), (pp.strides[0], _OS_BLOCK * pp.strides[1], pp.strides[1]))
    lower = np.partition(hood, k - 1, axis=-1)[..., k - 1]
    # Scale the order statistic to a mean-noise estimate for the SNR report: E[k-th of N cells]
    lower = lower / mean_kth
    # the test against each block's bound, block by block (no per-bin copy of the bound), with the
    # products the detector compares against (so a bin left out here fails it there too)
    cells = pp[:, reach:reach + n_blocks * _OS_BLOCK].reshape(rows, n_blocks, _OS_BLOCK)
    maybe = (cells > (scaled_alpha * lower)[..., None]).reshape(rows, n_blocks * _OS_BLOCK)[:, :n]   # rows may be 0
    r, c = np.nonzero(maybe | exact)
    noise = np.repeat(lower, _OS_BLOCK, axis=1)[:, :n]
    if r.size:
        win = np.lib.stride_tricks.sliding_window_view(pp[:, :n + 2 * reach], 2 * reach + 1, axis=-1)
        w = win[r, c]
        ref = np.concatenate([w[:, :n_ref_side], w[:, -n_ref_side:]], axis=1)
        noise[r, c] = np.partition(ref, k - 1, axis=-1)[:, k - 1] / mean_kth
    return noise.reshape(lead + (n,)), scaled_alpha * np.ones(n)


def _os_screened(p: np.ndarray, n_ref_side: int, n_guard: int, pfa: float,
                 rank: int | None, records: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The detector's sparse OS-CFAR: ``(r, c, noise, scaled_alpha)`` for the local maxima
    of ``p`` (rows, n) that may pass the threshold, with the exact statistic at each (as
    :func:`_noise_os` computes it); no local maximum left out passes ``p > scaled_alpha * noise``.

    Three screens, each a necessary condition of the exact test, so the decisions are the exact ones:
    1. per block of ``_OS_BLOCK`` bins, with its largest cell m: a cell c of the block passes only if
       the k-th smallest of its window is below p[c] / alpha <= m / alpha, so at least k cells of its
       window, hence of the block's neighbourhood (a superset), lie below m / alpha: a count against
       one threshold per block (no order statistic; the sort-free test that most blocks of noise fail);
    2. in the blocks left, the k-th smallest of the neighbourhood bounds every window from below
       (:func:`_noise_os`'s bound), per cell;
    3. a local maximum (the detector keeps no other cell)."""
    reach = n_guard + n_ref_side
    rows, n = p.shape
    if n <= reach:
        raise DspInputError(f"spectrum of {n} bins is too short for OS-CFAR reach {reach}")
    k, mean_kth, scaled_alpha, thr_factor = _os_constants(n_ref_side, pfa, rank, records)
    kern = jit.kernels(p.size)
    if kern is not None and rows:   # the same screen cell by cell in one compiled pass (lidard.dsp.spectrum.jit)
        return jit.os_screen(p, n_ref_side, n_guard, k, thr_factor, mean_kth, kern) + (scaled_alpha,)
    n_blocks = -(-n // _OS_BLOCK)
    pp = _mirror_padded(p, reach, n_blocks * _OS_BLOCK - n + reach)
    hood = np.lib.stride_tricks.as_strided(
        pp, (rows, n_blocks, _OS_BLOCK + 2 * reach), (pp.strides[0], _OS_BLOCK * pp.strides[1], pp.strides[1]))
    top = pp[:, reach:reach + n_blocks * _OS_BLOCK].reshape(rows, n_blocks, _OS_BLOCK).max(axis=-1)
    below = hood < (top * thr_factor)[..., None]
    rb, jb = np.nonzero(np.count_nonzero(below, axis=-1) >= k)
    lower = np.partition(hood[rb, jb], k - 1, axis=-1)[:, k - 1] / mean_kth
    c = jb[:, None] * _OS_BLOCK + np.arange(_OS_BLOCK)
    r = np.broadcast_to(rb[:, None], c.shape)
    inside = c < n
    pc = pp[r, np.where(inside, c, 0) + reach]
    ok = inside & (pc > scaled_alpha * lower[:, None])
    ok &= (pc >= pp[r, c + reach - 1]) | (c == 0)            # local maxima (beyond either edge: -inf)
    ok &= (pc > pp[r, c + reach + 1]) | (c == n - 1)
    r, c = r[ok], c[ok]
    win = np.lib.stride_tricks.sliding_window_view(pp[:, :n + 2 * reach], 2 * reach + 1, axis=-1)
    w = win[r, c]
    ref = np.concatenate([w[:, :n_ref_side], w[:, -n_ref_side:]], axis=1)
    noise = np.partition(ref, k - 1, axis=-1)[:, k - 1] / mean_kth
    return r, c, noise, scaled_alpha


def _os_constants(n_ref_side: int, pfa: float, rank: int | None, records: int = 1) -> tuple[int, float, float, float]:
    """(k, mean_kth, scaled_alpha, thr_factor) of OS-CFAR with ``2 n_ref_side`` reference cells, each the
    mean of ``records`` records' powers: the rank, E[k-th of N unit-mean cells], the factor on the noise
    (k-th / mean_kth) and the screens' factor on a cell's power (a cell c may pass only if its k-th
    smallest is below p[c] * thr_factor)."""
    n_ref = 2 * n_ref_side
    k = rank if rank is not None else max(1, int(round(0.75 * n_ref)))
    alpha = os_cfar_alpha(n_ref, k, float(pfa), records)     # checks k and records
    mean_kth = os_gamma_mean_kth(n_ref, k, int(records))
    # the margin covers the rounding of the detector's scaled_alpha * (kth / mean_kth) (a few ulps)
    return k, mean_kth, alpha * mean_kth, (1.0 + 1e-9) / alpha


def _os_detected(p: np.ndarray, n_ref_side: int, n_guard: int, pfa: float, rank: int | None, floor_factor: float,
                 kern: SimpleNamespace | None, records: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(r, c, noise) of the cells of ``p`` (rows, n) OS-CFAR detects, row-major: the local maxima with
    p > scaled_alpha * noise, noise > 0 and p > ``floor_factor`` times the row's largest cell.

    ``kern`` (:func:`lidard.dsp.spectrum.jit.kernels`): in one compiled pass that also checks the values (None
    if one is NaN, infinite or negative); None: :func:`_os_screened` and the test in numpy."""
    if kern is not None:
        if p.shape[-1] <= n_guard + n_ref_side:
            raise DspInputError(f"spectrum of {p.shape[-1]} bins is too short for OS-CFAR reach {n_guard + n_ref_side}")
        k, mean_kth, scaled_alpha, thr_factor = _os_constants(n_ref_side, pfa, rank, records)
        return jit.os_detect(p, n_ref_side, n_guard, k, thr_factor, mean_kth, scaled_alpha, floor_factor, kern)
    r, c, nz, scaled_alpha = _os_screened(p, n_ref_side, n_guard, pfa, rank, records)
    floor = floor_factor * p.max(axis=-1)
    pr = p[r, c]
    ok = (pr > scaled_alpha * nz) & (nz > 0) & (pr > floor[r])
    return r[ok], c[ok], nz[ok]


def _mirror_padded(p: np.ndarray, reach: int, tail: int) -> np.ndarray:
    """``p`` (rows, n) with ``reach`` mirrored cells on each side (np.pad's "reflect": the edge cell
    is not repeated), as the exact windows see it, then zeros up to ``tail`` cells after the last
    cell (a zero only lowers the block bound). One pass, no intermediate padded copy."""
    rows, n = p.shape
    pp = np.empty((rows, reach + n + tail))
    pp[:, reach:reach + n] = p
    pp[:, :reach] = p[:, reach - np.arange(reach)]
    pp[:, reach + n:2 * reach + n] = p[:, n - 2 - np.arange(reach)]
    pp[:, 2 * reach + n:] = 0.0
    return pp


_OS_BLOCK = 16   # bins per lower-bound block of the OS-CFAR (cost ~ (16 + 2 reach) / (16 n_ref) of exact)
