"""What a return predicts on every segment of a chirp period (dissertation §2.1.2, eqs. 2-4..2-7).

A return at range R with radial velocity v (positive receding) beats at the range frequency
f_R = 2 kappa R / c shifted by its Doppler f_D = -2 v / lambda (the bench's sign convention):

    up ramp:   f_R - f_D         down ramp:  f_R + f_D         hold (three-segment):  f_D

A real (single-photodiode) receiver sees the magnitudes; an I/Q receiver the signed frequencies
(the DSP conjugates the down ramp so that a static return sits at +f_R on both ramps: the down
ramp's line is then at f_R + f_D as well). The frame DSP pairs the ramps' detections by these
relations (:mod:`lidard.dsp.ranging.velocity`, :mod:`lidard.dsp.ranging.threeseg`); :func:`render` gives the
noise-free records of a set of returns (the model's expectation: the benchmarks and tests draw their
pixels from it, benchmarks/resolution_table.py). Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..spectrum.rangefft import C_M_PER_S


@dataclass(frozen=True)
class Lines:
    """The beat frequencies (Hz) of returns (any shape) on each segment, signed (I/Q convention)."""

    up_hz: np.ndarray
    down_hz: np.ndarray
    hold_hz: np.ndarray

    def observed(self, iq: bool) -> Lines:
        """What the receiver sees: the signed lines (I/Q) or their magnitudes (real)."""
        if iq:
            return self
        return Lines(np.abs(self.up_hz), np.abs(self.down_hz), np.abs(self.hold_hz))


def lines(range_m, velocity_mps, *, chirp_rate_hz_per_s: float, wavelength_m: float) -> Lines:
    """The lines of returns at ``range_m`` moving at ``velocity_mps`` (module doc)."""
    f_r = 2.0 * chirp_rate_hz_per_s * np.asarray(range_m, dtype=np.float64) / C_M_PER_S
    f_d = -2.0 * np.asarray(velocity_mps, dtype=np.float64) / wavelength_m
    return Lines(f_r - f_d, f_r + f_d, np.broadcast_to(f_d, np.shape(f_r)).copy())


def render(ln: Lines, amplitude_v, phase_rad: np.ndarray, *, fs_hz: float, ramp_samples: int,
           cw_samples: int = 0, iq: bool = False) -> np.ndarray:
    """Noise-free records (..., 2 ramp_samples + cw_samples) of returns along the last axis of ``ln``'s
    arrays (..., K): amplitude (V) ``amplitude_v`` (..., K), start phases ``phase_rad`` (..., K, 3) per
    segment (up, down, hold). Real: sum of A cos(2 pi f t + phi); I/Q: A exp(j (2 pi f t + phi)) with
    the down ramp's line conjugated back (the receiver's view of f_R + f_D on a falling chirp)."""
    t_r = np.arange(ramp_samples) / fs_hz
    t_c = np.arange(cw_samples) / fs_hz
    amp = np.asarray(amplitude_v, dtype=np.float64)[..., None]
    ph = np.asarray(phase_rad, dtype=np.float64)
    segs = []
    for f, t, p, conj in ((ln.up_hz, t_r, ph[..., 0], False), (ln.down_hz, t_r, ph[..., 1], True),
                          (ln.hold_hz, t_c, ph[..., 2], False)):
        arg = 2 * np.pi * np.asarray(f)[..., None] * t + p[..., None]
        if iq:
            z = amp * np.exp(1j * arg)
            segs.append((np.conj(z) if conj else z).sum(axis=-2))
        else:
            segs.append((amp * np.cos(arg)).sum(axis=-2))
    return np.concatenate(segs, axis=-1)
