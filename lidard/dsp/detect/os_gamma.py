"""OS-CFAR's false-alarm probability on averaged spectra (incoherent averaging of K records).

The frame DSP detects on the power of a pixel's K records averaged cell by cell. In noise alone a
record's cell is exponential (chi-square with 2 dof), so the averaged cell is Gamma(K) (chi-square with
2K dof over 2K): the noise of K records is far less spread than one record's, and at Rohling's factor
(exponential cells) a detector on averaged spectra alarms at a rate orders of magnitude below the one it
states. The exact rate for Gamma(K) cells (scale-free, so unit scale below) is

    Pfa(alpha) = E_Z[ P(X > alpha Z) ] = int_0^inf f_Z(z) Q_K(alpha z) dz

with X ~ Gamma(K) the cell under test, Z the k-th smallest of the N reference cells (iid Gamma(K)),
Q_K(t) = P(X > t) = exp(-t) sum_{j<K} t^j / j! (integer K) and the order statistic's density

    f_Z(z) = N! / ((k-1)! (N-k)!) F(z)^(k-1) Q_K(z)^(N-k) f(z),   f(z) = z^(K-1) exp(-z) / (K-1)!.

At K = 1 it is Rohling's prod_{i<k} (N-i) / (N-i+alpha). The integral is taken by the trapezoid rule
in s = ln z (the integrand is smooth and falls off exponentially in s on both sides, where the rule
converges geometrically); the weights are normalised by the same rule's integral of f_Z, so a
truncation of the grid cancels. Both tails are summed in their numerically stable form (the series
of P(K, t) below the mean, of Q_K(t) above it), in logarithms. Pure numpy and math.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

#: the quadrature's grid in s = ln(z / K) (z in units of one record's noise power): [S_LO, S_HI]. The
#: k-th of N Gamma(K) cells has mass below e^S_LO K only ~(e^S_LO)^(K k) (< e^-36 for every K, k >= 1)
#: and above e^S_HI K ~ exp(-K e^S_HI) (e^-403 K): both ends carry nothing the rate can see
S_LO, S_HI = -36.0, 6.0
#: points of the grid per unit of s, times ceil(sqrt(K) / 8): the order statistic's spread in s is
#: ~1 / sqrt(K k) and the rule needs a few points across it (the K = 1 rule matches Rohling's closed
#: form to ~1e-15, tests/dsp/detect/test_dsp_os_gamma.py)
POINTS_PER_S = 48


def _series_terms(records: int) -> int:
    """Terms of the tail series: the m-th term relative to the first is < exp(-m^2 / (2 K)) on the
    side each series is used on, so 10 sqrt(K) + 40 leave < e^-50."""
    return int(10 * math.sqrt(records)) + 40


def log_tails(t: np.ndarray, records: int) -> tuple[np.ndarray, np.ndarray]:
    """(ln P(K, t), ln Q_K(t)) of Gamma(K) (unit scale) at ``t`` > 0: the lower and upper tails.

    Below the mean (t < K) P(K, t) = exp(-t) t^K / K! sum_m t^m / ((K+1)...(K+m)) and Q = 1 - P; above
    it Q_K(t) = exp(-t) t^(K-1) / (K-1)! sum_m (K-1)...(K-m) / t^m and P = 1 - Q: each series has
    positive terms falling faster than a geometric one, and 1 - (the small tail) loses nothing."""
    t = np.asarray(t, dtype=np.float64)
    k = int(records)
    m = _series_terms(k)
    log_p = np.empty_like(t)
    log_q = np.empty_like(t)
    low = t < k
    tl = t[low]
    ser = 1.0 + np.cumprod(tl[:, None] / (k + 1.0 + np.arange(m)), axis=1).sum(axis=1)
    log_p[low] = -tl + k * np.log(tl) - math.lgamma(k + 1.0) + np.log(ser)
    log_q[low] = np.log1p(-np.exp(log_p[low]))
    th = t[~low]
    r = np.arange(min(k - 1, m))
    ser = 1.0 + np.cumprod((k - 1.0 - r)[None, :] / th[:, None], axis=1).sum(axis=1)
    log_q[~low] = -th + (k - 1) * np.log(th) - math.lgamma(float(k)) + np.log(ser)
    log_p[~low] = np.log1p(-np.exp(log_q[~low]))
    return log_p, log_q


@lru_cache(maxsize=64)
def _order_statistic(n_ref: int, k: int, records: int) -> tuple[np.ndarray, np.ndarray]:
    """The grid z (unit-scale Gamma(K) power) and the normalised trapezoid weights of f_Z(z) dz on it."""
    points = int((S_HI - S_LO) * POINTS_PER_S * math.ceil(math.sqrt(records) / 8.0)) + 1
    s = np.linspace(S_LO, S_HI, points)
    z = records * np.exp(s)
    log_p, log_q = log_tails(z, records)
    log_c = math.lgamma(n_ref + 1.0) - math.lgamma(float(k)) - math.lgamma(n_ref - k + 1.0)
    log_f = (records - 1) * np.log(z) - z - math.lgamma(float(records))
    # f_Z(z) dz = f_Z(z) z ds; the trapezoid's end weights are half (both ends carry ~nothing anyway)
    log_w = log_c + (k - 1) * log_p + (n_ref - k) * log_q + log_f + np.log(z)
    w = np.exp(log_w - log_w.max())
    w[[0, -1]] *= 0.5
    w /= w.sum()
    return z, w


def os_gamma_pfa(alpha: float, n_ref: int, k: int, records: int) -> float:
    """Pfa of OS-CFAR (k-th of ``n_ref`` cells) when every cell is the mean of ``records`` exponential
    records (Gamma(K) noise), for the threshold factor ``alpha`` on the k-th cell (module doc)."""
    if alpha <= 0.0:
        return 1.0
    z, w = _order_statistic(int(n_ref), int(k), int(records))
    return float(np.dot(w, np.exp(log_tails(alpha * z, records)[1])))


@lru_cache(maxsize=256)
def os_gamma_mean_kth(n_ref: int, k: int, records: int) -> float:
    """E[k-th smallest of ``n_ref`` cells] for unit-mean cells averaged over ``records`` records: the
    factor that turns the order statistic into a mean-noise estimate (K = 1: sum_{i=N-k+1}^{N} 1/i)."""
    if records == 1:
        return float(np.sum(1.0 / np.arange(n_ref - k + 1, n_ref + 1)))
    z, w = _order_statistic(int(n_ref), int(k), int(records))
    return float(np.dot(w, z)) / records
