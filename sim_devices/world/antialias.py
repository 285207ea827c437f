"""The digitizer's anti-alias/decimation filter acting on synthesized beat tones.

The synthesis works at the record's own rate fs, so a beat above fs/2 comes out already folded: a
filter run on the record afterwards could not tell it from an in-band tone. The filter is therefore
applied where a real digitizer applies it, before the rate reduction: each return's amplitude is
scaled, sample by sample, by |G| at its TRUE instantaneous beat frequency (the derivative of the
beat phase, which the synthesis has unwrapped: up ramp, down ramp, Doppler and the turning points
alike). The decimation filter is linear phase with its delay compensated (a zero-phase response),
so only the amplitude changes. The noise needs no such step: the filter's transition band is power
complementary about fs/2, so the folded noise stays white at fs (lidard.physics.decimation).

Returns whose beat cannot leave the pass band anywhere in the record (bounded by tau x the largest
chirp rate + |Doppler|) are left alone: no per-sample work for in-gate targets. For the others only
the record samples near a fast part of the chirp are looked at (:func:`column_rates`: the largest
chirp rate within reach of each sample bounds its beat), so a record whose chirp leaves the band
only at its turning points costs a few columns, not a pass over every sample.
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Callable

import numpy as np


@dataclass(frozen=True)
class BeatFilter:
    """|G(f)| of the digitizer's anti-alias filter at true beat frequencies, for one record rate."""

    response: Callable[[np.ndarray], np.ndarray]
    passband_hz: float      # |G| = 1 below: returns that stay below are not touched


def max_chirp_rate_hz_per_s(nu_hz: np.ndarray, fs_awg_hz: float) -> float:
    """Largest |d nu / dt| of a periodic, linearly interpolated optical frequency."""
    return float(np.max(_interval_rates(nu_hz, fs_awg_hz)))


def _interval_rates(nu_hz: np.ndarray, fs_awg_hz: float) -> np.ndarray:
    """|d nu / dt| on each interval [i, i + 1] of a periodic, linearly interpolated frequency."""
    nu = np.asarray(nu_hz, dtype=np.float64)
    return np.abs(np.diff(nu, append=nu[:1])) * float(fs_awg_hz)


#: column bounds kept per trajectory (one per record geometry and reach; a scan uses one or two)
_COLUMN_BOUNDS_KEPT = 16


def trajectory_rates(traj) -> tuple[np.ndarray, float]:
    """(|d nu / dt| per AWG interval, its maximum) of a ChirpTrajectory, computed once per trajectory."""
    got = traj._cache.get("aa_rates")
    if got is None:
        r = _interval_rates(traj.nu_hz, traj.fs_hz)
        got = traj._cache["aa_rates"] = (r, float(r.max()))
    return got


def column_rates(traj, x0: float, ratio: float, n: int, reach_awg: float) -> np.ndarray:
    """R[k]: the largest chirp rate (Hz/s) on the AWG intervals that the beat of record sample k can
    depend on, for records starting at AWG position ``x0`` with ``ratio`` AWG samples per record
    sample and delays of at most ``reach_awg`` AWG samples.

    The beat phase of a delay d is P(X) - P(X - d) at X_k = x0 + k ratio, so the frequency that
    sample_gains estimates at k (a difference over X_{k-1}..X_{k+1}) is an average of
    nu(y) - nu(y - d) over that span, and |nu(y) - nu(y - d)| <= tau max|d nu/dt| over [y - d, y]:
    every return of delay tau and Doppler f_D has |f(k)| <= tau R[k] + |f_D|. Cached on the
    trajectory (a scan's reads share one geometry)."""
    extend = int(np.ceil((max(reach_awg, 0.0) + 2.0) / ratio))     # whole columns the delay reaches back
    key = (float(x0), float(ratio), int(n), extend)
    kept = traj._cache.setdefault("aa_columns", {})
    got = kept.get(key)
    if got is not None:
        return got
    rate, _ = trajectory_rates(traj)
    j = np.arange(-1 - extend, n + 1)                 # segment j spans [X_j, X_{j+1}]
    edge = np.floor(x0 + j * ratio).astype(np.int64)  # the AWG interval holding X_j
    i0 = int(edge[0]) - 1
    vals = rate[np.arange(i0, int(edge[-1]) + 2) % rate.size]
    b = edge - i0
    # the largest rate on the intervals touching [X_j, X_{j+1}], one margin interval each side
    seg = np.maximum.reduceat(vals, b[:-1] - 1)
    for e in (-1, 0, 1):
        np.maximum(seg, vals[b[1:] + e], out=seg)
    # R[k] = max over segments k - 1 - extend .. k (segment index j + 1 + extend)
    out = seg[extend + 1:extend + 1 + n].copy()
    for s in range(1, extend + 2):
        np.maximum(out, seg[extend + 1 - s:extend + 1 - s + n], out=out)
    if len(kept) >= _COLUMN_BOUNDS_KEPT:
        kept.clear()
    kept[key] = out
    return out


def sample_gains(dphi: np.ndarray, fs_hz: float, filt: BeatFilter, bound_hz: np.ndarray, *,
                 turns: bool = False, cols: np.ndarray | None = None):
    """(rows, cols, gains) of the samples of ``dphi`` (n_hits, n) whose beat leaves the pass band, for
    the returns that may (screened by ``bound_hz`` per hit): gains = |G(f_inst)| there; |G| = 1 exactly
    everywhere else (the bound is a worst case over the record: on the calibrated chirp only the few
    samples at its turning points leave the band), so the caller scales those samples alone. None
    when no sample leaves the band. ``turns``: ``dphi`` is in cycles (rad / 2 pi), as the synthesis'
    static fast path gives it. ``cols``: the only samples (ascending) whose beat may leave the band
    (:func:`column_rates`); the answer is the same as without it, for less work."""
    rows = np.flatnonzero(np.asarray(bound_hz) > filt.passband_hz)
    if rows.size == 0:
        return None
    n = dphi.shape[1]
    if n < 2:
        return None
    scale = fs_hz if turns else fs_hz / (2.0 * np.pi)
    if cols is not None:
        return _gains_at(dphi, rows, np.asarray(cols, dtype=np.intp), n, scale, filt)
    x = dphi[rows] if rows.size < dphi.shape[0] else dphi
    # |d dphi / dk| x scale: numpy.gradient's differences (central inside, one-sided at the ends;
    # halving is exact, so scale / 2 gives its values bit for bit)
    f = np.empty(x.shape)
    np.subtract(x[:, 2:], x[:, :-2], out=f[:, 1:-1])
    f[:, 1:-1] *= 0.5 * scale
    f[:, 0] = (x[:, 1] - x[:, 0]) * scale
    f[:, -1] = (x[:, -1] - x[:, -2]) * scale
    np.abs(f, out=f)
    r, c = np.nonzero(f > filt.passband_hz)
    if r.size == 0:
        return None
    return rows[r], c, filt.response(f[r, c])


def _gains_at(dphi: np.ndarray, rows: np.ndarray, cols: np.ndarray, n: int, scale: float, filt: BeatFilter):
    """sample_gains on the rows ``rows`` and columns ``cols`` of ``dphi`` only: the same differences
    and products per sample (the values bit for bit), the same (row, column) order."""
    if cols.size == 0:
        return None
    left, right = np.maximum(cols - 1, 0), np.minimum(cols + 1, n - 1)
    r = rows[:, None]
    f = dphi[r, right] - dphi[r, left]
    f *= np.where((cols > 0) & (cols < n - 1), 0.5 * scale, scale)
    np.abs(f, out=f)
    r, c = np.nonzero(f > filt.passband_hz)
    if r.size == 0:
        return None
    return rows[r], cols[c], filt.response(f[r, c])
