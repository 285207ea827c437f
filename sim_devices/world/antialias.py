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
chirp rate + |Doppler|) are left alone: no per-sample work for in-gate targets.
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
    nu = np.asarray(nu_hz, dtype=np.float64)
    return float(np.max(np.abs(np.diff(nu, append=nu[:1])))) * float(fs_awg_hz)


def sample_gains(dphi: np.ndarray, fs_hz: float, filt: BeatFilter, bound_hz: np.ndarray, *,
                 turns: bool = False):
    """(rows, cols, gains) of the samples of ``dphi`` (n_hits, n) whose beat leaves the pass band, for
    the returns that may (screened by ``bound_hz`` per hit): gains = |G(f_inst)| there; |G| = 1 exactly
    everywhere else (the bound is a worst case over the record: on the calibrated chirp only the few
    samples at its turning points leave the band), so the caller scales those samples alone. None
    when no sample leaves the band. ``turns``: ``dphi`` is in cycles (rad / 2 pi), as the synthesis'
    static fast path gives it."""
    rows = np.flatnonzero(np.asarray(bound_hz) > filt.passband_hz)
    if rows.size == 0:
        return None
    x = dphi[rows] if rows.size < dphi.shape[0] else dphi
    n = x.shape[1]
    if n < 2:
        return None
    scale = fs_hz if turns else fs_hz / (2.0 * np.pi)
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
