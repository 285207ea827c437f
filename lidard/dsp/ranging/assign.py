"""Which ramp peaks are one return: joint (R, v) hypotheses scored by likelihood (§2.1.2, eqs. 2-4..2-7).

Every pairing of an up-ramp peak i with a down-ramp peak j is a hypothesis: a return whose lines
(:mod:`.lines`) sit at those two beats, with one amplitude (the two ramps of one period see the same
target, link and speckle). Its log-likelihood ratio against noise, with the amplitude fitted and each
record's phase free (the records' start phases differ), is, in noise-normalised powers x = |X|^2 / sigma^2
averaged over the pixel's L records (x ~ SNR per cell),

    Lambda_ij = L (sqrt(x_i) + sqrt(x_j))^2 / 2  =  L (x_i + x_j) - L (sqrt(x_i) - sqrt(x_j))^2 / 2:

the sum of the noise-normalised powers at the predicted lines (the detector's statistic) less the
deviance of the common amplitude. A true peak's own partner explains it better than a noise peak or
another return's peak does: no power-agreement rule is needed. Which hypotheses may be points at all is
the chirp's business (the speed prior of a triangle, the hold's line of a three-segment chirp:
:mod:`lidard.dsp.ranging.velocity`, :mod:`lidard.dsp.ranging.threeseg`), each peak at most one return's.

The assignment maximises the total log-likelihood over every set of hypotheses that uses each peak at
most once (:func:`best_matching`, exhaustive over the few peaks a ramp keeps), not greedily first-come.
Where two assignments explain the spectra equally well (two equal static returns a few cells apart:
the straight pairs and the crossed ones, whose Doppler is the returns' separation, have the same
likelihood), the data cannot choose and the prior does: a scene is mostly still, and the assignment
that needs the least motion is taken among those within a likelihood ratio ``tie_llr`` of the best
(a chi-square(1) quantile at the model-order level: "not significantly worse").

The false-point rate is set by the lines' detection (each at the per-ramp level q that makes
``scan.pfa`` the rate of false points, :mod:`.points`); this scorer only chooses among detected lines.
Pure numpy.
"""

from __future__ import annotations

from functools import lru_cache
from itertools import combinations, permutations

import numpy as np

from ..detect.cfar import Detections
from .order import chi2_isf


def pair_loglik(x_up: np.ndarray, x_down: np.ndarray, records: int) -> np.ndarray:
    """Lambda_ij (..., K_up, K_down) of the module doc from the noise-normalised line powers x_up
    (..., K_up) and x_down (..., K_down), each averaged over ``records`` records."""
    a = np.sqrt(np.maximum(np.asarray(x_up, dtype=np.float64), 0.0))[..., :, None]
    b = np.sqrt(np.maximum(np.asarray(x_down, dtype=np.float64), 0.0))[..., None, :]
    return 0.5 * float(records) * (a + b) ** 2


def tie_llr(level: float) -> float:
    """Two assignments whose log-likelihoods differ by less than this are equally good fits: half the
    chi-square(1) quantile exceeded with probability ``level`` (the model-order level)."""
    return 0.5 * float(chi2_isf(level, 1.0))


@lru_cache(maxsize=32)
def _matchings(ku: int, kd: int) -> np.ndarray:
    """(M, ku) every partial one-to-one map of up slots to down slots (-1: unpaired), the empty one first."""
    out = []
    for k in range(min(ku, kd) + 1):
        for ups in combinations(range(ku), k):
            for downs in permutations(range(kd), k):
                m = [-1] * ku
                for i, j in zip(ups, downs):
                    m[i] = j
                out.append(m)
    return np.array(out, dtype=np.int64).reshape(-1, ku)


def best_matching(score: np.ndarray, motion: np.ndarray, tie: float) -> np.ndarray:
    """Per row, the down slot paired with each up slot (n, K_up), -1 for none: the set of allowed pairs
    (``score`` (n, K_up, K_down) finite: log-likelihood ratios, -inf: not a hypothesis) whose total
    score is largest; among those within ``tie`` of it, the one with the least total ``motion``
    (n, K_up, K_down: |f_D| of each pair) and as many pairs. Each peak used at most once."""
    score = np.asarray(score, dtype=np.float64)
    n, ku, kd = score.shape
    out = np.full((n, ku), -1, dtype=np.int64)
    allowed = np.isfinite(score)
    # rows with at most one allowed pair per up and per down slot need no search (most pixels)
    busy = (allowed.sum(axis=2) > 1).any(axis=1) | (allowed.sum(axis=1) > 1).any(axis=1)
    easy = np.flatnonzero(~busy)
    if easy.size:
        a = allowed[easy]
        out[easy] = np.where(a.any(axis=2), np.argmax(a, axis=2), -1)
    rows = np.flatnonzero(busy)
    if rows.size == 0:
        return out
    m = _matchings(ku, kd)                                             # (M, ku)
    s = np.concatenate([np.where(allowed[rows], score[rows], -np.inf), np.zeros((rows.size, ku, 1))], axis=2)
    mo = np.concatenate([np.asarray(motion, dtype=np.float64)[rows], np.zeros((rows.size, ku, 1))], axis=2)
    pick = np.where(m >= 0, m, kd)                                     # the "unpaired" column
    up = np.arange(ku)
    total = s[:, up, pick].sum(axis=-1)                                # (rows, M)
    move = mo[:, up, pick].sum(axis=-1)
    best = total.max(axis=1, keepdims=True)
    pairs = (m >= 0).sum(axis=1)
    n_best = pairs[np.argmax(total, axis=1)][:, None]
    # near-best: as many pairs as the best (a weak pair is not traded for less motion)
    near = (total >= best - tie) & (pairs[None, :] == n_best)
    # the least motion among the near-best; the largest likelihood breaks what is left
    key = np.where(near, -move, -np.inf)
    top = key >= key.max(axis=1, keepdims=True) - 1e-9 * np.abs(key.max(axis=1, keepdims=True))
    choice = np.argmax(np.where(top, total, -np.inf), axis=1)
    out[rows] = m[choice]
    return out


def line_snr(du: Detections, dd: Detections) -> tuple[np.ndarray, np.ndarray]:
    """Two ramps' detections (:class:`lidard.dsp.detect.cfar.Detections`, (..., K)) as the pair likelihood's
    noise-normalised powers x (0 where no detection), over one noise level per pixel: the receiver's
    noise is the same on both ramps, and a per-detection local estimate (the CFAR's reference cells, a
    neighbour's skirt in them) would move one line's x against the other's by tens of percent."""
    dets = (du, dd)
    w = sum(np.count_nonzero(d.valid, axis=-1) for d in dets)
    total = sum(np.where(d.valid, d.noise, 0.0).sum(axis=-1) for d in dets)
    noise = np.maximum(total / np.maximum(w, 1), 1e-300)[..., None]
    return np.where(du.valid, du.power / noise, 0.0), np.where(dd.valid, dd.power / noise, 0.0)
