"""Chirp arithmetic (§2.1): chirp rate, beat frequency <-> range, triangle and three-segment drives,
ADC plan.

The three-segment waveform is the triangle followed by a constant-frequency segment: the
drive holds between the end of the down ramp and the start of the next up ramp, so the segment's beat
is the Doppler shift alone (docs/physics.md derives the pairing).

Pure numpy; no I/O.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from .constants import C_M_PER_S


def beat_hz(range_m: ArrayLike, chirp_rate_hz_per_s: float) -> np.ndarray:
    """f_b = 2 gamma d / c (eq. 2-1)."""
    return 2.0 * chirp_rate_hz_per_s * np.asarray(range_m) / C_M_PER_S


def range_resolution_m(excursion_hz: float) -> float:
    """delta d = c / (2 B) (eq. 2-3)."""
    return C_M_PER_S / (2.0 * excursion_hz)


def triangle_drive_v(excursion_hz: float, ramp_s: float, fs_hz: float, static_tuning_hz_per_v: float) -> np.ndarray:
    """One period (2 ramp_s long) of a plain triangular drive: optical up-chirp, then down-chirp.

    The amplitude is excursion / |tuning| and the drive is centred on 0 V; its sign follows the
    tuning so that the *optical* frequency rises during the first half (for a DFB, whose static
    tuning is negative, the drive voltage falls during the optical up-chirp).
    ``ramp_s * fs_hz`` must be (close to) an integer: the AWG period is a whole number of samples.
    """
    for name, v in (("excursion_hz", excursion_hz), ("ramp_s", ramp_s), ("fs_hz", fs_hz)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"triangle_drive: {name} must be positive and finite, got {v!r}")
    if not math.isfinite(static_tuning_hz_per_v) or static_tuning_hz_per_v == 0:
        raise ValueError(f"triangle_drive: static_tuning_hz_per_v must be finite and non-zero, got {static_tuning_hz_per_v!r}")
    n_ramp_f = ramp_s * fs_hz
    n_ramp = int(round(n_ramp_f))
    if n_ramp < 2 or abs(n_ramp_f - n_ramp) > 1e-6 * max(1.0, n_ramp_f):
        raise ValueError(f"triangle_drive: ramp_s * fs_hz = {n_ramp_f!r} must be an integer >= 2")
    k = np.arange(2 * n_ramp, dtype=np.float64)
    s = np.where(k <= n_ramp, k / n_ramp, (2 * n_ramp - k) / n_ramp)
    return (excursion_hz / static_tuning_hz_per_v) * (s - 0.5)


def hold_segment_v(drive_v: np.ndarray, n_hold: int) -> np.ndarray:
    """``drive_v`` (one triangle period) followed by ``n_hold`` samples that hold its level.

    The hold goes in a straight line from the last sample to the first (a learned drive need not end
    exactly where it starts), so the periodic waveform has no step; for a plain triangle it is flat.
    """
    d = np.asarray(drive_v, dtype=np.float64)
    if d.ndim != 1 or d.size < 2:
        raise ValueError(f"hold_segment: drive_v must be a 1-D period of >= 2 samples, got shape {d.shape}")
    if int(n_hold) != n_hold or n_hold < 0:
        raise ValueError(f"hold_segment: n_hold must be a whole number >= 0, got {n_hold!r}")
    w = (np.arange(int(n_hold)) + 1.0) / (int(n_hold) + 1.0)
    return np.concatenate([d, d[-1] + (d[0] - d[-1]) * w])


def three_segment_drive_v(excursion_hz: float, ramp_s: float, cw_s: float, fs_hz: float,
                          static_tuning_hz_per_v: float) -> np.ndarray:
    """One period (2 ramp_s + cw_s) of the plain three-segment drive: up, down, constant frequency."""
    n_cw_f = cw_s * fs_hz
    n_cw = int(round(n_cw_f))
    if not (math.isfinite(cw_s) and cw_s > 0) or abs(n_cw_f - n_cw) > 1e-6 * max(1.0, n_cw_f):
        raise ValueError(f"three_segment_drive: cw_s * fs_hz = {n_cw_f!r} must be a positive integer")
    return hold_segment_v(triangle_drive_v(excursion_hz, ramp_s, fs_hz, static_tuning_hz_per_v), n_cw)


def adc_rate_hz(max_range_m: float, chirp_rate_hz_per_s: float, *, max_doppler_hz: float = 0.0,
                oversample: float = 2.5, max_rate_hz: float = 1e9, min_rate_hz: float = 1e6,
                ramp_s: float | None = None) -> float:
    """Slowest rate max_rate / k (integer clock divider) that holds the highest beat ``oversample``x Nyquist.

    Simulate and capture only what the requested range needs: the rate (and so the record length)
    grows with the maximum range, never a fixed high rate.
    """
    if not (max_range_m > 0 and chirp_rate_hz_per_s > 0 and oversample >= 2):
        raise ValueError("adc_rate_hz: max_range_m > 0, chirp_rate_hz_per_s > 0, oversample >= 2 required")
    need = float(oversample * (beat_hz(max_range_m, chirp_rate_hz_per_s) + abs(max_doppler_hz)))
    need = max(need, min_rate_hz)
    if need > max_rate_hz:
        raise ValueError(f"max range {max_range_m} m needs an ADC rate of {need / 1e6:.1f} MHz, above the "
                         f"digitizer's {max_rate_hz / 1e6:.0f} MHz")
    divider = max(1, int(math.floor(max_rate_hz / need)))
    if ramp_s is not None:
        # a ramp must be a whole number of samples (the record holds exactly up + down ramp)
        while divider > 1 and abs(max_rate_hz / divider * ramp_s - round(max_rate_hz / divider * ramp_s)) > 1e-6:
            divider -= 1
    return max_rate_hz / divider
