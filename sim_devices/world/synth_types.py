"""What beat synthesis takes and gives (``sim_devices.world.synth``): the digitizer's recording
format, the returns to synthesize, the records, and the one error type of the synthesis.

* :class:`AdcSpec`: samples per trigger, rate, bits and full scale (+-input_range_v / 2, eq. 2-19's
  V_ADC being the peak-to-peak range), real or I/Q, quantized or volts;
* :class:`HitBatch`: one row per return (segment, delay tau = 2 d / c, amplitude G_TIA I_AC of
  eq. 2-11, optical Doppler f_D = -2 v / lambda of eqs. 2-4/2-5, optional speckle phase), validated
  against the batch;
* :class:`Effects`, :class:`MonitorMzi`, :class:`SynthOutputs`: what the synthesis adds to the clean
  beat (white noise, phase noise, DC, the receiver's filter and hybrid), the monitor MZI channel(s),
  and what it returns besides the records;
* :class:`Synthesized`: the records (codes or volts) per channel, overrange flags and, on request,
  the analog volts and the phase-noise realization.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from typing import Any

import numpy as np

from lidard.physics.constants import C_M_PER_S
from sim_devices.world.antialias import BeatFilter


class SynthError(ValueError):
    """Invalid synthesis input; the message names the argument and the bad value."""


@dataclass(frozen=True)
class AdcSpec:
    """What the digitizer records per trigger: ``n_samples`` at ``sample_rate_hz``.

    Full scale is +-input_range_v / 2 with 2**bits codes (see the module docstring). ``iq``: two
    channels I and Q for the LiDAR beat. ``quantize=False`` returns clipped float volts.
    """

    sample_rate_hz: float
    n_samples: int
    bits: int = 8
    input_range_v: float = 1.0
    iq: bool = False
    quantize: bool = True

    def __post_init__(self):
        if not (math.isfinite(self.sample_rate_hz) and self.sample_rate_hz > 0):
            raise SynthError(f"AdcSpec: sample_rate_hz must be positive and finite, got {self.sample_rate_hz!r}")
        if int(self.n_samples) != self.n_samples or self.n_samples < 1:
            raise SynthError(f"AdcSpec: n_samples must be a positive integer, got {self.n_samples!r}")
        if int(self.bits) != self.bits or not 1 <= self.bits <= 16:
            raise SynthError(f"AdcSpec: bits must be an integer in 1..16, got {self.bits!r}")
        if not (math.isfinite(self.input_range_v) and self.input_range_v > 0):
            raise SynthError(f"AdcSpec: input_range_v must be positive and finite, got {self.input_range_v!r}")

    @property
    def lsb_v(self) -> float:
        return self.input_range_v / 2.0 ** self.bits

    @property
    def code_min(self) -> int:
        return -(1 << (self.bits - 1))

    @property
    def code_max(self) -> int:
        return (1 << (self.bits - 1)) - 1

    @classmethod
    def from_config(cls, adc, sample_rate_hz: float, n_samples: int, *, quantize: bool = True) -> AdcSpec:
        """From a :class:`lidard.config.Adc` section."""
        return cls(sample_rate_hz=float(sample_rate_hz), n_samples=int(n_samples), bits=int(adc.bits),
                   input_range_v=float(adc.input_range_v), iq=bool(adc.iq), quantize=quantize)


@dataclass(frozen=True)
class HitBatch:
    """Returns to synthesize: one entry per (segment, target) pair.

    ``seg``: index of the segment (0..n_seg-1); ``tau_s``: round-trip delay 2 d / c at the segment's
    start time; ``amplitude_v``: beat amplitude at the ADC input, G_TIA I_AC (eq. 2-11);
    ``doppler_hz``: optical Doppler shift of the return, f_D = -2 v_radial / lambda with v_radial > 0
    RECEDING (so f_D < 0 for a receding target, f_D = +2 V / lambda for an approaching speed V);
    ``phase_rad``: optional constant beat phase (e.g. speckle); default 2 pi nu0 tau (mod 2 pi).
    """

    seg: np.ndarray
    tau_s: np.ndarray
    amplitude_v: np.ndarray
    doppler_hz: np.ndarray | None = None
    phase_rad: np.ndarray | None = None

    @classmethod
    def empty(cls) -> HitBatch:
        return cls(seg=np.zeros(0, np.intp), tau_s=np.zeros(0), amplitude_v=np.zeros(0))

    @classmethod
    def from_targets(cls, seg, distance_m, amplitude_v, *, radial_velocity_m_s=None,
                     wavelength_m: float = 1.55e-6, phase_rad=None) -> HitBatch:
        """Convenience: distance (m) and radial velocity (m/s, positive receding) to tau and f_D."""
        d = np.asarray(distance_m, dtype=np.float64)
        dop = None
        if radial_velocity_m_s is not None:
            dop = -2.0 * np.asarray(radial_velocity_m_s, dtype=np.float64) / wavelength_m * np.ones_like(d)
        return cls(seg=np.asarray(seg), tau_s=2.0 * d / C_M_PER_S,
                   amplitude_v=np.asarray(amplitude_v, dtype=np.float64) * np.ones_like(d),
                   doppler_hz=dop, phase_rad=phase_rad)

    def validated(self, n_seg: int):
        seg = np.asarray(self.seg)
        if seg.ndim != 1:
            raise SynthError(f"HitBatch.seg must be 1-D, got shape {seg.shape}")
        n = seg.size
        if n and not np.issubdtype(seg.dtype, np.integer):
            raise SynthError(f"HitBatch.seg must hold integer segment indices, got dtype {seg.dtype}")
        seg = seg.astype(np.intp)
        if n and (seg.min() < 0 or seg.max() >= n_seg):
            raise SynthError(f"HitBatch.seg: indices must be in 0..{n_seg - 1}, got {seg.min()}..{seg.max()}")

        def arr(name, v, default):
            a = np.full(n, default, dtype=np.float64) if v is None else np.asarray(v, dtype=np.float64)
            if a.shape == ():
                a = np.full(n, float(a))
            if a.shape != (n,):
                raise SynthError(f"HitBatch.{name}: expected shape ({n},) like seg, got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise SynthError(f"HitBatch.{name}: contains NaN or inf")
            return a

        tau = arr("tau_s", self.tau_s, 0.0)
        if n and tau.min() < 0:
            raise SynthError(f"HitBatch.tau_s: delays must be >= 0, got min {tau.min()!r}")
        amp = arr("amplitude_v", self.amplitude_v, 0.0)
        dop = arr("doppler_hz", self.doppler_hz, 0.0)
        ph = None if self.phase_rad is None else arr("phase_rad", self.phase_rad, 0.0)
        return seg, tau, amp, dop, ph


@dataclass(frozen=True)
class Effects:
    """What the synthesis adds to the clean beat; every one off by default (nothing random drawn).

    ``noise_asd_v_per_rthz``: scalar or per-segment white-noise ASD of the LiDAR channel(s);
    ``linewidth_hz``: the laser's Lorentzian linewidth (one Wiener phase per segment, shared with the
    monitor MZI); ``dc_v``: offset of the beat channels; ``beat_filter``: the digitizer's anti-alias
    filter at each return's true beat frequency (:mod:`sim_devices.world.antialias`; None: an ideal
    one, nothing beyond fs/2 is synthesized); ``iq_imbalance``: (g, eps) of the coherent receiver's
    90-degree hybrid, the Q channel being g A sin(dPhi + eps) ((1, 0): an ideal hybrid).
    """

    noise_asd_v_per_rthz: Any = 0.0
    linewidth_hz: float = 0.0
    dc_v: float = 0.0
    beat_filter: BeatFilter | None = None
    iq_imbalance: tuple[float, float] = (1.0, 0.0)


@dataclass(frozen=True)
class MonitorMzi:
    """The monitor MZI recorded beside the beat: its delay, fringe amplitude and white-noise ASD;
    ``quadrature``: also its 90-degree output (channel ``mzi_q``, sin of the same phase, as a hybrid
    or 3x3 coupler and a second digitizer channel give; its own noise draws)."""

    delay_s: float
    amplitude_v: float
    noise_asd_v_per_rthz: float = 0.0
    quadrature: bool = False


@dataclass(frozen=True)
class SynthOutputs:
    """What the synthesis returns besides the records: the analog ``volts`` of every channel, the
    ``phase_noise`` realization; ``fast_trig`` (default: the ADC's ``quantize``) evaluates cos/sin in
    float32 after an exact float64 range reduction (error ~1e-7 of the amplitude, invisible after
    quantization); unquantized output uses float64 trig so that volts compare to 1e-9."""

    volts: bool = False
    phase_noise: bool = False
    fast_trig: bool | None = None


@dataclass
class Synthesized:
    """Digitizer records for ``n_seg`` segments.

    ``beat``: (n_seg, n) int16 codes (float64 volts if not quantized) -- the real beat, or I for I/Q;
    ``beat_q``: Q channel or None; ``mzi``: monitor-MZI channel or None; ``overrange``: (n_seg,
    len(channels)) bool, a channel clipped somewhere in that segment; ``channels`` names the columns.
    ``volts`` (if ``SynthOutputs.volts``): the analog channels before clipping/quantization.
    ``phase_noise_rad`` (if ``SynthOutputs.phase_noise``): the Wiener realization (n_seg, n_pre + n) on the
    ADC grid, sample k of the record being column ``n_pre + k``; None when the linewidth is 0.
    """

    beat: np.ndarray
    beat_q: np.ndarray | None
    mzi: np.ndarray | None
    overrange: np.ndarray
    channels: tuple[str, ...]
    lsb_v: float
    volts: dict | None = None
    phase_noise_rad: np.ndarray | None = None
    phase_noise_pre: int = 0
    mzi_q: np.ndarray | None = None     # quadrature monitor output (``mzi_quadrature``): sin where mzi is cos
