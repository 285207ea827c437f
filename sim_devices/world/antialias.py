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
    """(rows, gains) for the returns of ``dphi`` (n_hits, n) whose beat may leave the pass band
    (``bound_hz`` per hit), gains (len(rows), n) = |G(f_inst)|; None when no return can.
    ``turns``: ``dphi`` is in cycles (rad / 2 pi), as the synthesis' static fast path gives it."""
    rows = np.flatnonzero(np.asarray(bound_hz) > filt.passband_hz)
    if rows.size == 0:
        return None
    f_inst = np.gradient(dphi[rows], axis=1) * (fs_hz if turns else fs_hz / (2.0 * np.pi))
    return rows, filt.response(f_inst)
