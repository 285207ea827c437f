"""What the CFAR detector does with its detections, split from :mod:`lidard.dsp.detect.cfar` (which re-exports
these names): the strongest ``max_detections`` per ramp, their -6 dB widths (the resolution test of
§2.4: two targets closer than the window's main lobe merge into one wider peak) and the harmonic
ghosts of clipping (a detection at ~2x/3x the frequency of a much stronger one).

Detections are few (about one per ramp in a frame), so each step works on the list of detected cells,
not on (ramps x slots) arrays: a per-ramp sort only where a ramp has several, the width search only
for the peaks whose crossing is not yet found, the harmonic test only on pairs of valid detections
(the results are those of the dense forms, bit for bit, tested in tests/dsp/detect/test_dsp_cfar_post.py).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from lidard.dsp.spectrum import jit
from lidard.dsp.spectrum.window import get_window

# (k, index, valid, power, noise, snr_db) of the strongest candidates per ramp (_strongest_cells)
_Strongest = tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _width_6db(p: np.ndarray, idx: np.ndarray, max_half: int, rows: np.ndarray | None = None,
               cols: np.ndarray | None = None) -> np.ndarray:
    """-6 dB (power 1/4) full width around each peak, linear interpolation of the crossings.

    Each side: the first of the ``max_half`` bins out from the peak below a quarter of its power,
    interpolated with the bin before it (``max_half`` if none is; past an edge the edge bin repeats).
    ``idx`` (..., K): peaks in the rows of ``p`` (..., n); or ``rows``/``cols``: the peaks are the cells
    (rows, cols) of ``p`` (n_rows, n) instead (result (m,))."""
    n = p.shape[-1]
    flat = p.reshape(-1)
    if rows is not None:
        return _widths_flat(flat, np.asarray(rows) * n, np.asarray(cols), n, max_half)
    starts = np.arange(flat.size // n if n else 0).reshape(idx.shape[:-1] + (1,)) * n
    start = np.broadcast_to(starts, idx.shape).reshape(-1)
    return _widths_flat(flat, start, np.asarray(idx).reshape(-1), n, max_half).reshape(idx.shape)


def _widths_flat(flat: np.ndarray, start: np.ndarray, col: np.ndarray, n: int, max_half: int) -> np.ndarray:
    """:func:`_width_6db` of the peaks at ``flat[start + col]`` (rows of ``n`` cells from ``start``).

    Step by step outwards, only for the peaks whose side has not crossed yet (most cross within two
    or three bins): the same values as reading all ``max_half`` offsets of every peak at once. With
    the compiled kernels (:mod:`lidard.dsp.spectrum.jit`) peak by peak, the same operations in the same order."""
    kern = jit.kernels(col.size)
    if kern is not None:
        return jit.widths_6db(flat, start, col, n, max_half, kern)
    peak = flat[start + col]
    level = peak / 4.0
    widths = np.zeros(col.shape)
    for direction in (-1, 1):
        half = np.full(col.shape, float(max_half))
        act = np.arange(col.size)
        prev = peak
        for s in range(max_half):
            if act.size == 0:
                break
            v = flat[start[act] + np.clip(col[act] + direction * (s + 1), 0, n - 1)]
            cross = v < level[act]
            done = act[cross]
            cur, before = v[cross], prev[cross]
            with np.errstate(divide="ignore", invalid="ignore"):
                frac = np.where(before > cur, (before - level[done]) / (before - cur), 0.0)
            half[done] = s + frac
            act, prev = act[~cross], v[~cross]
        widths += half
    return widths


@lru_cache(maxsize=32)
def _single_tone_width(window: str, zero_pad: int) -> float:
    """Largest -6 dB width (as measured by _width_6db on the bin grid) of one noise-free tone.

    The measured width of a sampled lobe depends on where the tone falls between bins (a tone
    half-way between two bins of a rectangular window looks 2.7 bins wide, on-bin 1.5), so the
    reference is the worst case over sub-bin offsets, not the continuous -6 dB width.
    """
    n = 256
    w = get_window(window, n)
    t = np.arange(n)
    widest = 0.0
    for delta in np.linspace(0.0, 0.5, 11):
        spec = np.fft.fft(w * np.exp(2j * np.pi * (64 + delta) * t / n), n * zero_pad)
        p = np.abs(spec) ** 2
        pk = np.array([[int(np.argmax(p))]])
        widest = max(widest, float(_width_6db(p[None, :], pk, 8 * zero_pad + 8)[0, 0]))
    return widest


def _strongest(p2: np.ndarray, noise: np.ndarray, cand: np.ndarray, max_detections: int) -> _Strongest:
    """:func:`_strongest_cells` of a dense candidate map (and a dense noise array)."""
    rows, cols = np.nonzero(cand)
    return _strongest_cells(p2, rows, cols, noise[rows, cols], max_detections)


def _strongest_cells(p2: np.ndarray, rows: np.ndarray, cols: np.ndarray, noise: np.ndarray,
                     max_detections: int) -> _Strongest:
    """The ``k`` strongest candidates (cells with their noise; the detector lists them row-major) per
    ramp, strongest first: (k, index, valid, power, noise, snr_db), (n_rows, k) each."""
    n_rows, n_bins = p2.shape
    k = min(max_detections, n_bins)
    # Candidates are few (about one per ramp): rank them per ramp instead of partitioning every
    # bin of every ramp, and sort only the ramps with several. Equal powers keep the
    # lower bin first (a stable sort of cells in row-major order); empty slots are invalid.
    pw = p2[rows, cols]
    count = np.bincount(rows, minlength=n_rows)
    order = np.arange(rows.size)
    if rows.size > 1 and np.any(rows[1:] < rows[:-1]):
        several = order.copy()          # not in row order: sort them all (ties keep the given order)
    else:                               # rows ascending: each ramp's candidates are one run, sorted within it
        several = np.flatnonzero(count[rows] > 1)
    if several.size:
        order[several] = several[np.lexsort((-pw[several], rows[several]))]
    rows, cols, pw, noise = rows[order], cols[order], pw[order], noise[order]
    rank = np.arange(rows.size) - (np.cumsum(count) - count)[rows]
    top = rank < k
    rows, rank = rows[top], rank[top]
    idx = np.zeros((n_rows, k), dtype=np.int64)
    valid = np.zeros((n_rows, k), dtype=bool)
    pk = np.zeros((n_rows, k))
    nz = np.zeros((n_rows, k))
    idx[rows, rank] = cols[top]
    valid[rows, rank] = True
    pk[rows, rank] = pw[top]
    nz[rows, rank] = noise[top]
    snr_db = np.full((n_rows, k), -np.inf)
    snr_db[rows, rank] = 10.0 * np.log10(pw[top] / noise[top])
    return k, idx, valid, pk, nz, snr_db


def _harmonic_ghosts(idx: np.ndarray, pk: np.ndarray, valid: np.ndarray, *, n_bins: int, iq: bool, zero_pad: int,
                     harmonic_ratio_db: float) -> np.ndarray:
    """Detections at the 2nd/3rd harmonic (aliased) of a much stronger one in the same ramp.

    Tested on the pairs (strong j, weak i) of valid slots of a ramp only, and the frequencies only
    for the pairs where j is stronger by the ratio (most ramps hold one detection)."""
    n_fft = (n_bins if iq else 2 * (n_bins - 1))
    harm = np.zeros(idx.shape, dtype=bool)
    ratio = 10 ** (harmonic_ratio_db / 10.0)
    tol = 1.5 * zero_pad
    rows, slots = np.nonzero(valid)                     # row-major: each ramp's valid slots are one run
    count = np.bincount(rows, minlength=idx.shape[0])
    first = np.cumsum(count) - count
    rep = count[rows]
    weak = np.repeat(np.arange(rows.size), rep)         # every (weak, strong) pair of a ramp
    strong = first[rows[weak]] + (np.arange(weak.size) - np.repeat(np.cumsum(rep) - rep, rep))
    fb = idx[rows, slots]
    fbin = (fb - n_fft // 2) if iq else fb
    pw = pk[rows, slots]
    louder = pw[strong] >= ratio * pw[weak]           # first: it leaves few pairs (self-pairs fail it if ratio > 1)
    weak, strong = weak[louder], strong[louder]
    fi, fj = fbin[weak], fbin[strong]
    ghost = np.zeros(rows.size, dtype=bool)
    for h in (2, 3):
        hf = h * fj.astype(np.float64)                  # stronger peak j -> its harmonic
        if iq:
            alias = (hf + n_fft / 2) % n_fft - n_fft / 2
        else:
            m = np.mod(hf, n_fft)
            alias = np.minimum(m, n_fft - m)
        hit = np.abs(fi - alias) <= tol * h
        ghost[weak[hit]] = True
    harm[rows, slots] = ghost
    return harm
