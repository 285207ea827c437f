"""The returns of a mixed pixel from its footprint samples, and the truth its point is scored against.

A beam footprint straddling an edge sees several surfaces (:mod:`sim_devices.world.footprint`
samples the footprint). A pixel's samples are
grouped into returns: a new return where the target changes or the depth jumps by more than one
range bin ``c / 2B`` (closer than that a real FMCW receiver cannot separate two tones: they blend).
Each return's weight is its share of the samples, i.e. of the beam power (the sunflower samples
are equal-power), and scales the beat amplitude (field sum over the footprint, §2.4 eq. 2-11 with
the power of that share).

Ground truth of a mixed pixel (:func:`nearest_truth`): the instrument measures one of the surfaces
in the footprint, or the blend of surfaces closer than a range bin (a blended tone lies between its
components). A point is therefore scored against the footprint's return nearest to it, or, for a
blend, against the nearest point of the blend's range interval; pixels without a mixed footprint
keep the central ray's first hit (the single-ray truth, unchanged).
"""

from __future__ import annotations

import numpy as np

__all__ = ["agreeing", "mix_samples", "nearest_truth"]


def agreeing(sample_targets: np.ndarray, central_targets: np.ndarray) -> np.ndarray:
    """(k,) True where every sample (k, N, max_hits target indices, -1 = none) sees the same targets
    in the same order as the central ray (k, max_hits): the pixel keeps its single ray. On one
    convex or planar target the depth is continuous across the footprint: a slanted surface's range
    spread is no mixed pixel (the fitted beat is its centre's)."""
    return np.all(sample_targets == central_targets[:, None, :], axis=(1, 2))


def mix_samples(columns: list[np.ndarray], bin_m: float, max_hits: int) -> list[tuple]:
    """Weighted returns of k mixed pixels from their samples' hits, vectorized over pixels.

    ``columns``: the 6 hit arrays of the samples (range, incidence, reflectivity, radial velocity,
    transmission, target index; each (k, N, max_hits), target -1 = no hit). Returns per pixel 7
    arrays (the 6 columns averaged over each return's samples, and its weight: its share of the N
    samples), nearest first, at most ``max_hits``. A sample that hits nothing adds to no return."""
    k, n, _ = columns[0].shape
    pix, samp, slot = np.nonzero(columns[5] >= 0)
    vals = [c[pix, samp, slot].astype(np.float64) for c in columns]
    tgt, rng = vals[5], vals[0]
    order = np.lexsort((rng, tgt, pix))
    pix, vals = pix[order], [v[order] for v in vals]
    tgt, rng = vals[5], vals[0]
    # a new return where the pixel or the target changes, or the depth jumps by more than a range bin
    new = np.r_[True, (pix[1:] != pix[:-1]) | (tgt[1:] != tgt[:-1]) | (np.diff(rng) > bin_m)]
    start = np.flatnonzero(new)
    count = np.diff(np.r_[start, pix.size])
    means = [np.add.reduceat(v, start) / count for v in vals]
    g_pix = pix[start]
    # per pixel: returns nearest first (the grouping sorted them by target)
    g_order = np.lexsort((means[0], g_pix))
    g_pix, means, weight = g_pix[g_order], [m[g_order] for m in means], count[g_order] / n
    bounds = np.searchsorted(g_pix, np.arange(k + 1))
    cols = [*means, weight]
    return [tuple(c[bounds[j]:min(bounds[j + 1], bounds[j] + max_hits)].copy() for c in cols)
            for j in range(k)]


def nearest_truth(measured_m: float, ranges_m: np.ndarray, bin_m: float) -> float:
    """The range a measurement is scored against among a mixed pixel's returns ``ranges_m``:
    returns chained within ``bin_m`` of each other form a blend interval [lo, hi]; the truth is the
    point of the nearest interval closest to the measurement (inf when there is no return)."""
    r = np.sort(np.asarray(ranges_m, np.float64)[np.isfinite(ranges_m)])
    if r.size == 0:
        return float("inf")
    if not np.isfinite(measured_m):
        return float(r[0])
    cuts = np.flatnonzero(np.diff(r) > bin_m) + 1
    best, best_d = float(r[0]), np.inf
    for seg in np.split(r, cuts):
        t = float(np.clip(measured_m, seg[0], seg[-1]))
        if abs(t - measured_m) < best_d:
            best, best_d = t, abs(t - measured_m)
    return best
