"""The honest range gate and the per-point flags (dissertation §2.1.1, §4.4.3).

A real beat sampled at fs cannot say on which side of a multiple of fs its tone was: a target
beyond the gate whose beat folds into it looks like one inside. Two things keep such folds out of
the points (lidard.physics.decimation has the filter model):

* the gate ends where the digitizer's decimation filter stops guaranteeing the band: at
  fs - f_stop (0.4 fs), the top of the alias-free band, whatever the nominal maximum range asks;
* inside it, a return folded from beyond has passed the stop band: it is at most the alias ceiling
  (stop-band gain x the core's full-scale amplitude; anything stronger clips the core and the
  segment is flagged over range). A detection no stronger than that (with ``ALIAS_MARGIN`` for the
  noise riding on it) is flagged ``ALIASED`` and never valid.

Why not tell the fold from the data? With a triangle chirp a folded static target gives the same up
and down beats as an in-gate static target (the fold flips the Doppler sign only), the two peaks'
ratio is the same, and changing the sample rate between averages doubles the acquisition. The
instrument knows its filter and its full scale, so the ceiling is exact and costs nothing; on the
default 100 dB filter it sits below the CFAR threshold, so no real in-gate return is given up.

Point flags (``flags`` field of lidard.instrument.types.POINT_DTYPE): a bit set says why a point
is not valid. Pure numpy.
"""

from __future__ import annotations

from enum import IntFlag
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ...physics.decimation import DecimationFilter

#: an alias's measured amplitude may exceed the ceiling by the noise on it: 6 dB of margin
ALIAS_MARGIN = 2.0
#: points are reported up to this factor x the scan's max_range_m: a surface at the gate's edge is not
#: dropped for its range noise or the bins' quantisation (the band searched holds beats that far: the
#: range beat of max_range_m plus the Doppler allowance); farther returns give no point at all
GATE_MARGIN = 1.05


def in_gate(range_m: np.ndarray, min_range_m: float, max_range_m: float) -> np.ndarray:
    """Whether each range lies in the gate [min_range_m, GATE_MARGIN x max_range_m]."""
    r = np.asarray(range_m)
    return (r >= min_range_m) & (r <= max_range_m * GATE_MARGIN)


class PointFlag(IntFlag):
    """Why a point is not valid (bits of the points' ``flags`` field; 0 = a clean point)."""

    UNRESOLVED = 1    # two or more surfaces closer than the range resolution merged into one peak
    ALIASED = 2       # no stronger than a fold of a return beyond the gate can be
    HARMONIC = 4      # at 2x/3x the beat of a much stronger return (clipping)
    AMBIGUOUS = 8     # no unambiguous up/down pairing (folding through DC, speed limit)
    CLIPPED = 16      # a record of the pixel clipped (over range)
    OUT_OF_BAND = 32  # radial speed beyond the Doppler band the digitizer was sized for (max_speed_mps)


def gate_top_hz(nominal_hz: float, alias_free_hz: float | None) -> float:
    """The gate's highest beat: the nominal one (range + Doppler allowance), cut at the top of the
    alias-free band when the digitizer decimates."""
    return float(nominal_hz) if alias_free_hz is None else min(float(nominal_hz), float(alias_free_hz))


def aliased(intensity_v: np.ndarray, ceiling_v: float) -> np.ndarray:
    """Detections no stronger than a folded out-of-gate return can be (``ceiling_v`` 0: none)."""
    return np.asarray(intensity_v) <= ALIAS_MARGIN * float(ceiling_v)


def point_flags(*, unresolved: ArrayLike, leak: ArrayLike, harmonic: ArrayLike, unpaired: ArrayLike) -> np.ndarray:
    """The uint8 flags of (pixel, return) slots from the DSP's boolean verdicts (``leak``: aliased)."""
    f = np.zeros(np.shape(unresolved), np.uint8)
    for mask, bit in ((unresolved, PointFlag.UNRESOLVED), (leak, PointFlag.ALIASED),
                      (harmonic, PointFlag.HARMONIC), (unpaired, PointFlag.AMBIGUOUS)):
        f |= np.where(mask, np.uint8(bit), np.uint8(0))
    return f


def out_of_band(present: np.ndarray, velocity_mps: np.ndarray, max_speed_mps: float,
                speed_cell_mps: float) -> np.ndarray:
    """Points whose radial speed lies beyond the band the digitizer was sized for (its Doppler
    allowance ``max_speed_mps``) by more than two speed cells (``speed_cell_mps`` = lambda / (2 T), the
    ramp's Doppler resolution: a target at the band's edge measured with noise stays in). Beyond the
    band the record's rate was not chosen to hold the beats: a point there may be a fold, so it is
    flagged OUT_OF_BAND and never valid, whatever its pairing said."""
    return np.asarray(present) & (np.abs(np.asarray(velocity_mps)) > float(max_speed_mps) + 2.0 * speed_cell_mps)


def decimation_gate(fs_hz: float, core_rate_hz: float, stopband_db: float, input_range_v: float) -> dict[str, Any]:
    """FrameDsp's ``alias_free_hz`` and ``alias_ceiling_v`` for a record at ``fs_hz`` decimated from a
    core at ``core_rate_hz`` (none at the core's own rate: only the analogue front end filters)."""
    if core_rate_hz / float(fs_hz) < 2.0 - 1e-9:
        return {"alias_free_hz": None, "alias_ceiling_v": 0.0}
    filt = DecimationFilter(stopband_db)
    return {"alias_free_hz": filt.alias_free_hz(fs_hz), "alias_ceiling_v": filt.alias_ceiling_v(input_range_v)}
