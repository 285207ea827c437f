"""Fast path of the beat synthesis for static returns on a rational sample grid.

Follows the same physics as :mod:`sim_devices.world.synth` (dissertation §2.1 eqs. 2-1..2-3): the
deterministic beat phase of a static return delayed by tau is

    dPhi_k = P(b + r k) - P(b + r k - d) + 2 pi nu_mean tau + phi0,   d = tau fs_awg,

where P is the periodic chirp phase (one quadratic per AWG interval: P(i + f) = c0[i] + f c1[i] +
f^2 c2[i]), b the record's first sample on the AWG grid and r = fs_awg / fs_adc. The general path
gathers c0, c1, c2 at every delayed sample (three element gathers and ~15 float64 passes per hit
and sample). When r = p / q with a small q (the sim's 100 MS/s AWG against a 40 MS/s record:
r = 5/2) the samples k = j, j + q, j + 2q, ... of one residue j fall on the AWG grid at i + p m with
ONE fractional position f for all m, both for the undelayed phase and for a hit's delayed one. The
integer offset between the two, delta = i_b - i_h, takes only a few values (d is a few AWG samples),
and for each it is the same for every hit, so per residue and delta three contiguous vectors
carry everything that does not depend on the hit:

    G[m]  = c0[i_b + p m] - c0[i_b - delta + p m] + f_b (c1[i_b + p m] + f_b c2[i_b + p m])
    H1[m] = c1[i_b - delta + p m],   H2[m] = c2[i_b - delta + p m]

and a hit with fraction f_h costs dPhi = G - f_h (H1 + f_h H2) - const: four passes, no gathers.
The big chirp phase (up to ~1e6 rad, float64 as the module docstring of synth.py explains) only
enters G through the difference of two c0 values, computed once in float64; the result is the
general path's value to ~1e-9 rad (tests/sim_devices/world/test_synth_grid.py).
"""

from __future__ import annotations

import math

import numpy as np

from sim_devices.world import synth_jit

#: largest denominator q of fs_awg / fs_adc taken by the fast path (q vectors per residue)
MAX_DENOMINATOR = 16


def rational_ratio(ratio: float, max_q: int = MAX_DENOMINATOR) -> tuple[int, int] | None:
    """(p, q) with ratio == p / q exactly in float64 and q <= max_q, or None."""
    if not (math.isfinite(ratio) and ratio > 0):
        return None
    for q in range(1, max_q + 1):
        p = round(ratio * q)
        if p > 0 and p / q == ratio:
            return p, q
    return None


def static_beat_phase(tables, b_start: float, ratio: float, pq: tuple[int, int], n: int,
                      d_awg: np.ndarray, const: np.ndarray) -> np.ndarray:
    """dPhi (n_hits, n) float64 of static returns delayed by ``d_awg`` AWG samples (module docstring).

    ``tables``: the tiled (c0, c1, c2) of :class:`ChirpTrajectory`, long enough for every position
    (as for the general path); ``b_start``: the record's first sample on the tiled AWG grid (>= the
    largest delay, so that every position is >= 0); ``const``: per-hit constant phase added.
    """
    c0, c1, c2 = tables
    d_awg = np.asarray(d_awg, dtype=np.float64)
    neg_const = -np.asarray(const, dtype=np.float64)
    out = np.empty((d_awg.size, n))
    kernel = synth_jit.static_fill(out.size)
    if kernel is not None and d_awg.size:      # one compiled pass, the same values (synth_jit)
        kernel(c0, c1, c2, float(b_start), float(ratio), int(pq[0]), int(pq[1]), int(n), d_awg,
               np.ascontiguousarray(neg_const), out)
        return out
    _fill(c0, c1, c2, b_start, ratio, pq, n, d_awg, neg_const[:, None], out)
    return out


def _fill(c0, c1, c2, b_start, ratio, pq, n, d_awg, neg_const, out) -> None:
    """static_beat_phase into ``out`` (n_hits, n): per residue j, per distinct delta."""
    p, q = pq
    nh = d_awg.size
    for j in range(min(q, n)):
        length = len(range(j, n, q))
        b = b_start + j * ratio
        ib = int(b)                                   # b >= 0: truncation is floor
        fb = b - ib
        span = slice(None, p * (length - 1) + 1, p)   # m = 0..length-1 at stride p
        x = b - d_awg
        ih = x.astype(np.intp)
        fh = (x - ih)[:, None]
        delta = ib - ih
        base_frac = fb * (c1[ib:][span] + fb * c2[ib:][span])
        dest = out[:, j::q]
        for dv in np.unique(delta):
            dv = int(dv)
            i0 = ib - dv
            g = c0[ib:][span] - c0[i0:][span]
            g += base_frac
            h1, h2 = c1[i0:][span], c2[i0:][span]
            rows = np.flatnonzero(delta == dv)
            whole = rows.size == nh
            f = fh if whole else fh[rows]
            o = np.multiply(h2, f, out=dest) if whole else h2 * f
            o += h1
            o *= f
            o += neg_const if whole else neg_const[rows]
            np.subtract(g, o, out=o)
            if not whole:
                dest[rows] = o
