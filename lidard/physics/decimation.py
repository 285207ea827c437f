"""The digitizer's decimation (anti-alias) filter, and what it means for the range gate.

The converter core samples at ``adc.max_sample_rate_hz`` (Table 2-2: 1 GS/s, behind the analogue
front end's ``adc.bandwidth_hz``); a record at a lower rate fs = f_core / D is decimated on board by a
digital down-converter. That is the class of digitizer modelled here: the DDC of a GS/s converter
(a cascade of half-band FIRs, often after a CIC stage, as in the DDCs of GS/s converters such as the
TI ADC12DJ/ADC32RF and ADI AD9680 families, or the "digital anti-alias FIR" of acquisition systems
such as the HBM GEN3i, whose data sheet gives 0.1 dB passband flatness and a 60 dB stop band). Its response, relative to the OUTPUT
rate fs (it tracks the rate, as those filters do):

* pass band 0 .. f_p = 0.4 fs: flat (the ripple, hundredths of a dB, is not modelled);
* transition f_p .. f_s = 0.6 fs = fs - f_p: the last half-band's, power complementary about fs/2,
  |G(f)|^2 + |G(fs - f)|^2 = 1 (here |G|^2 = cos^2(pi/2 (f - f_p) / (f_s - f_p)));
* stop band f >= f_s: ``stopband_db`` below the pass band (a flat floor: the real filter's lobes stay
  under it). 60 to over 100 dB across data sheets; ``adc.stopband_db`` = 100 dB by default: the
  alias ceiling below must sit under the record's noise, or weak true returns are given up (at 80 dB
  the ceiling, 50 uV at a 1 V range, doubled for the noise on it, is above the bench's CFAR threshold
  of ~70 uV for a record's weakest detections: half the points of a 25 m retro-reflective wall
  were flagged; at 100 dB none).

What follows for a real (single-photodiode) beat sampled at fs (dissertation §2.1.1: beat = chirp
rate x round trip, so a farther target is a higher beat):

* A beat at f folds to |f - k fs|. Everything that folds into 0 .. fs - f_s = 0.4 fs came from at
  least f_s, i.e. through the stop band: the ALIAS-FREE band ends at :meth:`alias_free_hz`. The range
  gate (beat + Doppler allowance) must end there, not at the nominal maximum range alone.
* The transition band folds onto itself (0.5 .. 0.6 fs lands on 0.4 .. 0.5 fs), outside that band.
* The noise folds too; power complementarity keeps the folded noise white at the record rate, so a
  record synthesized with white noise at fs is exactly the decimated record's noise.
* A folded return inside the gate is at most ``stopband`` x the largest amplitude the core can take
  without clipping (input_range / 2; a larger one clips the core and the segment is flagged over
  range): :meth:`alias_ceiling_v`. A detection no stronger than that cannot be told from a leak.

Pure: numpy and the standard library only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

#: pass-band edge and stop-band edge, as fractions of the OUTPUT sample rate (a half-band pair)
PASSBAND_FRACTION = 0.4
STOPBAND_FRACTION = 1.0 - PASSBAND_FRACTION


class DecimationError(ValueError):
    """A bad filter or rate argument; the message names it."""


@dataclass(frozen=True)
class DecimationFilter:
    """Amplitude response of the digitizer's decimation filter (module docstring)."""

    stopband_db: float = 100.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.stopband_db) and self.stopband_db > 0):
            raise DecimationError(f"stopband_db must be positive and finite, got {self.stopband_db!r}")

    @property
    def stopband_gain(self) -> float:
        return 10.0 ** (-self.stopband_db / 20.0)

    def gain(self, f_hz: ArrayLike, fs_hz: float) -> np.ndarray:
        """|G(f)| at beat frequencies ``f_hz`` (the sign is ignored: a real beat) for output rate fs."""
        fs = _rate(fs_hz)
        f = np.abs(np.asarray(f_hz, dtype=np.float64))
        fp, fstop = PASSBAND_FRACTION * fs, STOPBAND_FRACTION * fs
        x = np.clip((f - fp) / (fstop - fp), 0.0, 1.0)
        g = np.cos(0.5 * np.pi * x)
        return np.maximum(g, self.stopband_gain)

    @staticmethod
    def alias_free_hz(fs_hz: float) -> float:
        """Highest beat whose every alias source went through the stop band: fs - f_s."""
        return (1.0 - STOPBAND_FRACTION) * _rate(fs_hz)

    def alias_ceiling_v(self, input_range_v: float) -> float:
        """Largest amplitude a folded out-of-gate return can have in the record (V)."""
        if not (math.isfinite(input_range_v) and input_range_v > 0):
            raise DecimationError(f"input_range_v must be positive and finite, got {input_range_v!r}")
        return 0.5 * input_range_v * self.stopband_gain


def _rate(fs_hz: float) -> float:
    fs = float(fs_hz)
    if not (math.isfinite(fs) and fs > 0):
        raise DecimationError(f"fs_hz must be positive and finite, got {fs_hz!r}")
    return fs
