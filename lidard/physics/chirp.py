"""Chirp arithmetic (§2.1): chirp rate, beat frequency <-> range, triangle drive, ADC plan.

Pure numpy; no I/O.
"""

from __future__ import annotations

import math

import numpy as np

from .constants import C_M_PER_S


def beat_hz(range_m, chirp_rate_hz_per_s: float):
    """f_b = 2 gamma d / c (eq. 2-1)."""
    return 2.0 * chirp_rate_hz_per_s * np.asarray(range_m) / C_M_PER_S


def range_resolution_m(excursion_hz: float) -> float:
    """delta d = c / (2 B) (eq. 2-3)."""
    return C_M_PER_S / (2.0 * excursion_hz)


def triangle_drive_v(excursion_hz: float, ramp_s: float, fs_hz: float, tuning_hz_per_v: float) -> np.ndarray:
    """One period (up ramp then down ramp of the optical frequency) of a plain triangular drive.

    The amplitude is excursion / |tuning|; with a negative static tuning (a DFB's thermal tuning) the
    drive voltage falls while the optical frequency rises.
    """
    for name, v in (("excursion_hz", excursion_hz), ("ramp_s", ramp_s), ("fs_hz", fs_hz)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"triangle_drive_v: {name} must be positive and finite, got {v!r}")
    if not math.isfinite(tuning_hz_per_v) or tuning_hz_per_v == 0:
        raise ValueError(f"triangle_drive_v: tuning_hz_per_v must be non-zero, got {tuning_hz_per_v!r}")
    n = int(round(ramp_s * fs_hz))
    up = np.linspace(-0.5, 0.5, n, endpoint=False)
    nu = np.concatenate([up, -up]) * excursion_hz        # optical frequency, centred on 0
    return nu / tuning_hz_per_v


def adc_rate_hz(max_range_m: float, chirp_rate_hz_per_s: float, *, max_doppler_hz: float = 0.0,
                oversample: float = 2.5, max_rate_hz: float = 1e9, min_rate_hz: float = 1e6,
                ramp_s: float | None = None) -> float:
    """Slowest rate max_rate / k (integer clock divider) that holds the highest beat ``oversample``x Nyquist.

    Simulate and capture only what the requested range needs: the rate (and so the record length)
    grows with the maximum range, never a fixed high rate.
    """
    if not (max_range_m > 0 and chirp_rate_hz_per_s > 0 and oversample >= 2):
        raise ValueError("adc_rate_hz: max_range_m > 0, chirp_rate_hz_per_s > 0, oversample >= 2 required")
    need = oversample * (beat_hz(max_range_m, chirp_rate_hz_per_s) + abs(max_doppler_hz))
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
