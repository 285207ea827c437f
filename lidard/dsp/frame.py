"""Per-pixel ranging of a batch of digitizer segments: the scan engine's DSP (§2.1, §4.4.3).

A segment is one triangle period captured after one trigger: the up ramp then the down ramp, each
``ramp_samples`` long. For a batch of pixels with ``averages`` segments each this module

1. keeps the central ``use_fraction`` of each ramp (the chirp's turning points are not linear even
   after pre-distortion, whose region of interest is the middle of each ramp, §2.2),
2. takes the windowed range FFT of every ramp (:class:`RangeFFT`) and averages the powers over the
   segments of a pixel (incoherent averaging),
3. detects up to ``max_returns`` peaks per ramp with OS-CFAR at ``ramp_pfa``, the per-ramp level
   that makes ``pfa`` the rate of false points per range cell (:mod:`lidard.dsp.ranging.points`),
   inside the range gate widened by the Doppler allowance,
4. refines each detection to a fractional bin once per pixel: the segments of a pixel share the
   frequency (their amplitudes and phases are their own), so its maximum-likelihood estimate
   maximises the sum of the segments' likelihoods (the default ``newton`` estimator; the others
   refine every segment and average, as the dissertation averages 10 distance measurements a pixel);
   a ramp's several detections are refined jointly and every detection is tested against the fitted
   tones (:mod:`lidard.dsp.ranging`: no mutual leakage bias; ``unresolved`` by a model-order test at
   ``order_level``; a return hidden beside a stronger one is added),
5. pairs up- and down-ramp peaks (eqs. 2-6, 2-7) by the likelihood of joint (range, velocity)
   hypotheses (:mod:`lidard.dsp.ranging.assign`): range, radial velocity (positive receding),
   validity (folding, harmonic ghosts, unresolved peaks are flagged, not reported as clean points).
   With a three-segment chirp (``cw_samples`` > 0: the record holds a constant-frequency segment after
   the ramps) the CW spectrum joins the pairing and no speed prior is used (:mod:`.threeseg`).

Only paired detections become points; unpaired peaks (mostly noise) are dropped. Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from functools import cached_property
from typing import Any

import numpy as np

from .chain import detect_and_refine
from .detect.cfar import CfarSettings
from .ranging.estimators import DEFAULT_METHOD
from .detect.gate import PointFlag, aliased, gate_top_hz, in_gate, out_of_band, point_flags
from .ranging.iqbalance import check_imbalance, correct, mirror_images, ramp_volts
from .pnframe import compensated_front_end
from .spectrum.rangefft import C_M_PER_S, RangeFFT
from .ranging.cwhold import HoldProfile
from .ranging.cwhold import CW_GUARD_BINS
from .ranging.threeseg import cw_front_end, cw_window, drift_rho, pair_frame_three
from .ranging.assign import line_snr
from .ranging.points import hypotheses_per_cell, ramp_pfa
from .ranging.ramp import RampModel, refine_ramp
from .spectrum.scratch import scratch
from .ranging.velocity import pair_up_down_matched
from .spectrum.window import WindowName

#: the range window: the central fraction of each ramp the range estimator keeps (step 1 above). The
#: chirp's pre-distortion linearizes over the same window (its region of interest): the range scale of
#: a scan is the chirp's mean slope over it, so the two must be the one figure
#: (lidard.instrument.calibration.linearization)
RANGE_WINDOW_FRACTION = 0.9


@dataclass(frozen=True)
class FrameResult:
    """Per pixel and return slot (n_pix, K): only entries with ``present`` are points."""

    present: np.ndarray
    valid: np.ndarray
    range_m: np.ndarray
    velocity_mps: np.ndarray
    snr_db: np.ndarray
    intensity_v: np.ndarray
    flags: np.ndarray | None = None     # uint8 lidard.dsp.detect.gate.PointFlag bits (why not valid)

    def refused(self, where: np.ndarray, flag: PointFlag) -> FrameResult:
        """These returns are not valid, for this reason: ``where`` (broadcast to (n_pix, K)) loses
        ``valid`` and gains ``flag`` (a speed past the band, a clipped record)."""
        where = np.broadcast_to(np.asarray(where, dtype=bool), self.valid.shape)
        if not where.any():
            return self
        flags = np.zeros(self.valid.shape, np.uint8) if self.flags is None else self.flags
        return replace(self, valid=self.valid & ~where, flags=flags | np.where(where, np.uint8(flag), np.uint8(0)))


def keep_returns(res: FrameResult, k: int) -> FrameResult:
    """The ``k`` slots of each pixel that matter most: valid points first, then drawn ones, each by SNR."""
    if res.present.shape[-1] <= k:
        return res
    key = (np.where(res.present & res.valid, 2.0, np.where(res.present, 1.0, 0.0)) * 1e6
           + np.clip(np.nan_to_num(res.snr_db, nan=-1e5), -1e5, 1e5) / 10)
    order = np.argsort(-key, axis=-1, kind="stable")[..., :k]
    pick = {f: np.take_along_axis(getattr(res, f), order, axis=-1) for f in
            ("present", "valid", "range_m", "velocity_mps", "snr_db", "intensity_v")}
    if res.flags is not None:
        pick["flags"] = np.take_along_axis(res.flags, order, axis=-1)
    return FrameResult(**pick)


#: settings a capture recorded before they were fields ran with, where today's default differs: its
#: replay then builds the DSP its scan ran (the harmonic screen's level was a fixed 15 dB)
_BEFORE_RECORDED: dict[str, Any] = {"sfdr_dbc": 15.0}


@dataclass(frozen=True)
class FrameDsp:
    ramp_samples: int
    fs_hz: float
    chirp_rate_hz_per_s: float
    wavelength_m: float
    max_range_m: float
    min_range_m: float = 0.05
    max_speed_mps: float = 5.0
    window: WindowName = "hann"
    # the rate of valid false points per range cell (one ramp FFT bin of the searched band) in noise
    # alone; the per-ramp detector runs at the looser ramp_pfa (lidard.dsp.ranging.points). 1e-11: the
    # per-ramp level 1e-6 on the scan's three-segment chirp (m = 10), the operating point it was tuned at
    pfa: float = 1e-11
    max_returns: int = 2
    use_fraction: float = RANGE_WINDOW_FRACTION
    estimator: str = DEFAULT_METHOD
    iq: bool = False            # I/Q receiver: process() takes beat (I) and beat_q (Q), two-sided spectra
    iq_gain: float = 1.0        # its calibrated imbalance (lidard.dsp.ranging.iqbalance): Q / I gain ratio ...
    iq_phase_rad: float = 0.0   # ... and quadrature phase error, removed before the FFT
    cw_samples: int = 0         # samples of the constant-frequency segment after the ramps (0: triangle)
    # the held segment's measured drift (lidard.dsp.ranging.cwhold.HoldProfile.as_dict; the linearization's):
    # where the real receiver's two regimes meet, |f_D| comes from the dechirped CW segment
    hold_profile: dict[str, Any] | None = None
    # the digitizer's decimation filter (lidard.physics.decimation, lidard.dsp.detect.gate): the top of its
    # alias-free band caps the gate; a detection no stronger than the alias ceiling (V) is flagged
    alias_free_hz: float | None = None
    alias_ceiling_v: float = 0.0
    # the model-order test's level (lidard.dsp.ranging.order): the probability that one clean return
    # is flagged unresolved (its cells not explained by the fitted tones) by noise alone
    order_level: float = 1e-3
    # the receiver's spurious-free dynamic range while nothing clips (adc.sfdr_dbc): a peak at 2x / 3x a
    # stronger one's beat is screened as its harmonic only when it is at least this far below it
    sfdr_dbc: float = 40.0

    def __post_init__(self) -> None:
        if not 0.2 <= self.use_fraction <= 1.0:
            raise ValueError(f"use_fraction must be in [0.2, 1], got {self.use_fraction!r}")
        if not self.max_range_m > self.min_range_m >= 0:
            raise ValueError(f"need max_range_m > min_range_m >= 0, got {self.max_range_m}, {self.min_range_m}")
        if self.iq and self.cw_samples:
            raise ValueError("an I/Q receiver measures the beat's sign on the triangle: no constant-frequency segment")
        check_imbalance(self.iq_gain, self.iq_phase_rad)
        if not 0.0 < self.order_level < 1.0:
            raise ValueError(f"order_level must be in (0, 1), got {self.order_level!r}")
        _ = self.ramp_pfa       # a false-point rate the per-ramp detector cannot give is refused here

    def to_record(self) -> dict[str, Any]:
        """Every field, JSON-ready: what a raw capture stores under ``dsp`` (:meth:`from_record`)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_record(cls, record: dict[str, Any], **overrides: Any) -> FrameDsp:
        """The FrameDsp a capture recorded (:meth:`to_record`), ``overrides`` over it: a replay runs
        exactly the DSP the scan built (its fields, not today's configuration, decide the points)."""
        unknown = set(record) - {f.name for f in fields(cls)}
        if unknown:
            raise ValueError(f"recorded dsp fields {sorted(unknown)} are not FrameDsp settings "
                             "(written by another lidard version?)")
        return cls(**{**_BEFORE_RECORDED, **record, **overrides})

    @property
    def n_used(self) -> int:
        return int(self.ramp_samples * self.use_fraction) & ~1

    @property
    def offset(self) -> int:
        return (self.ramp_samples - self.n_used) // 2

    # What depends only on the geometry is built once per FrameDsp (the instrument calls process()
    # on every batch of reads): the RangeFFT with its window, and the searched bin range.
    # cached_property writes the instance __dict__ directly, so it works on a frozen dataclass.
    @cached_property
    def rfft(self) -> RangeFFT:
        return RangeFFT(self.n_used, self.fs_hz, self.chirp_rate_hz_per_s, window=self.window, iq=self.iq)

    @cached_property
    def hold(self) -> HoldProfile | None:
        """``hold_profile`` parsed and checked once (not on every batch)."""
        return HoldProfile.from_dict(self.hold_profile)

    @cached_property
    def drift_rho(self) -> tuple[float, float] | None:
        """The measured drift rate's range over the CW window (:func:`lidard.dsp.ranging.threeseg.drift_rho`)."""
        return None if self.hold is None else drift_rho(self, self.hold)

    @cached_property
    def bin_range(self) -> tuple[int, int]:
        """(first, last) spectrum index searched by CFAR: the range gate plus the Doppler allowance."""
        return self._bin_range(self.rfft)

    @cached_property
    def ramp_pfa(self) -> float:
        """The per-ramp detector's false-alarm probability per cell that makes ``pfa`` the rate of false
        points per range cell (:mod:`lidard.dsp.ranging.points`)."""
        lo, hi = self.bin_range
        guard = None
        if self.cw_samples:
            guard = CW_GUARD_BINS * self.fs_hz / cw_window(self)[1]
        m = hypotheses_per_cell(ramp_cell_hz=self.fs_hz / self.n_used, band_cells=(hi - lo + 1) // self.rfft.zero_pad,
                                doppler_max_hz=2 * self.max_speed_mps / self.wavelength_m, static_guard_hz=guard)
        return ramp_pfa(self.pfa, m)

    @property
    def cfar(self) -> CfarSettings:
        """The per-ramp detector's settings (every front end's and the spectrum view's): OS-CFAR at
        ``ramp_pfa`` over the gate's bins, ``candidate_slots`` peaks, and the harmonic screen at the
        receiver's spurious-free dynamic range (``sfdr_dbc``): a record that clipped gives no valid
        point whatever the screen says, so only the unclipped receiver's harmonics are screened."""
        return CfarSettings(method="os", pfa=self.ramp_pfa, max_detections=self.candidate_slots, window=self.window,
                            iq=self.iq, bin_range=self.bin_range, harmonic_ratio_db=self.sfdr_dbc)

    @property
    def candidate_slots(self) -> int:
        """Peaks kept per ramp by the candidate search: ``max_returns`` and as many more as the noise
        alarms the per-ramp level lets through the band (the median of their Poisson count, round(q x
        cells)): a noise peak must not take a return's slot (two equal returns two cells apart lost the
        second one in ~35 % of pixels at q = 3e-4 without them). The points are then cut back to
        ``max_returns`` (:func:`keep_returns`)."""
        lo, hi = self.bin_range
        return self.max_returns + round(self.ramp_pfa * (hi - lo + 1) / self.rfft.zero_pad)

    @property
    def pixel_ml(self) -> bool:
        """The ``newton`` estimator is the likelihood of a tone in white noise: on a pixel's records,
        which share the frequency, it is maximised once on their summed likelihood
        (:func:`lidard.dsp.ranging.ramp.refine_ramp`), not once per record and averaged. The other
        estimators refine every record and take the mean."""
        return self.estimator == "newton"

    @property
    def max_drift_bins(self) -> float:
        """How far a return's beat moves from one record to the next at the band's speed: its range
        changes by max_speed x the record period, its beat by 2 gamma / c per metre (bins of the
        ramp's N-point grid). The per-pixel refinement fits that drift (at most this) with the frequency."""
        period_s = (2 * self.ramp_samples + self.cw_samples) / self.fs_hz
        return 2 * self.chirp_rate_hz_per_s * self.max_speed_mps * period_s / C_M_PER_S * self.n_used / self.fs_hz

    @property
    def range_resolution_m(self) -> float:
        return C_M_PER_S / (2 * self.chirp_rate_hz_per_s * self.n_used / self.fs_hz)

    def measurement_delay_s(self, averages: int) -> float:
        """From a pixel's first trigger (a point's ``t``) to the instant its range refers to: the two
        ramps' beats give the range at their mean centre, one ramp time after a trigger, averaged over
        the pixel's triggers ((averages - 1) / 2 periods later still). A target at 5 m/s moves 0.4 mm
        in the 80 us of one average (a hold-out check against moving targets measured this offset)."""
        period_s = (2 * self.ramp_samples + self.cw_samples) / self.fs_hz
        return self.ramp_samples / self.fs_hz + 0.5 * (int(averages) - 1) * period_s

    def sidecar(self, phase_noise: bool, path: str | None = None) -> dict[str, Any]:
        """The ``dsp`` block of a scan's sidecar (the scan loop's and a reprocessing's alike);
        ``path``: the DSP path the points were computed on (lidard.dsp.spectrum.jit.DspPath)."""
        out = {"window": self.window, "estimator": self.estimator, "pfa": self.pfa,
               "range_resolution_m": self.range_resolution_m, "use_fraction": self.use_fraction,
               "phase_noise_compensation": phase_noise, "receiver": "iq" if self.iq else "real",
               # three-segment: the linearization's measured drift of the held segment resolves the
               # regimes' meeting (|f_D| ~ f_R); without it such pixels are drawn, not valid
               "hold_profile": self.hold_profile is not None}
        if path is not None:
            out["path"] = path
        return out

    def spectrum_cells(self, pixels: int, averages: int) -> int:
        """Spectrum cells the DSP's calls go over for ``pixels`` of ``averages`` records, as they count
        them for the compiled kernels (lidard.dsp.spectrum.jit): each ramp's range spectrum of every
        record, and the pixel's averaged spectrum in the OS-CFAR's two passes. The size of a job in the
        DSP path's cost model (lidard.dsp.spectrum.jit.plan_path)."""
        return int(pixels) * 2 * (int(averages) + 2) * int(self.rfft.spectrum_shape((1,))[-1])

    def _bin_range(self, rf: RangeFFT) -> tuple[int, int]:
        """A real beat is searched over [f_R,min - D, f_R,max + D] folded to >= 0; an I/Q beat (the
        down ramp conjugated, so that both ramps put a static target at +f_R) over the same signed
        band, which may reach below 0 Hz (a Doppler larger than the range beat does not fold)."""
        doppler = 2 * self.max_speed_mps / self.wavelength_m
        f_lo = 2 * self.chirp_rate_hz_per_s * self.min_range_m / C_M_PER_S - doppler
        f_hi = gate_top_hz(2 * self.chirp_rate_hz_per_s * self.max_range_m / C_M_PER_S + doppler,
                           self.alias_free_hz)
        df = rf.delta_f
        if self.iq:
            f_lo = max(f_lo, -gate_top_hz(self.fs_hz / 2, self.alias_free_hz))
            lo = int(rf.bin_to_index(int(np.floor(f_lo / df))))
            hi = min(int(rf.bin_to_index(int(np.ceil(f_hi / df)) + 2)), rf.n_fft - 1)
            return max(lo, 0), hi
        n_bins = rf.n_fft // 2 + 1
        lo = int(np.floor(max(f_lo, 0.0) / df))
        hi = min(int(np.ceil(f_hi / df)) + 2, n_bins - 1)
        return lo, hi

    def process(self, beat: np.ndarray, lsb_v: float = 1.0, *, mzi: np.ndarray | None = None,
                mzi_delay_s: float | None = None, mzi_lsb_v: float = 1.0,
                mzi_q: np.ndarray | None = None, beat_q: np.ndarray | None = None) -> FrameResult:
        """``beat``: (n_pix, averages, 2 * ramp_samples) real samples (codes or volts); with ``iq`` the
        I channel, and ``beat_q`` the Q channel (same shape and LSB; its imbalance is corrected here).

        ``mzi``: the monitor MZI recorded in the same segments (same shape): laser phase-noise
        compensation (§2.3, :mod:`lidard.dsp.pnframe`) with the monitor delay ``mzi_delay_s``;
        ``mzi_q``: the same MZI's quadrature output (second monitor channel, same shape and LSB as
        ``mzi``): compensation at every range, not only at multiples of the delay.
        """
        x = np.asarray(beat)
        if x.ndim != 3 or x.shape[-1] < 2 * self.ramp_samples:
            raise ValueError(f"beat must be (n_pix, averages, >= {2 * self.ramp_samples}), got {x.shape}")
        if x.shape[0] == 0:     # no pixel (e.g. an empty last chunk of a raw capture cut by a kill)
            z = np.zeros((0, self.max_returns))
            return FrameResult(present=z.astype(bool), valid=z.astype(bool), range_m=z, velocity_mps=z, snr_db=z,
                               intensity_v=z, flags=z.astype(np.uint8))
        if self.iq:
            if beat_q is None:
                raise ValueError("an I/Q FrameDsp needs beat_q (the Q channel) beside beat (I)")
            x = correct(x, beat_q, self.iq_gain, self.iq_phase_rad)
        elif beat_q is not None:
            raise ValueError("beat_q given to a FrameDsp built with iq=False")
        if mzi is not None:     # same chain and pairing on the compensated spectrum
            if mzi_delay_s is None:
                raise ValueError("mzi given without mzi_delay_s (the monitor MZI delay)")
            out_f, out_det = compensated_front_end(self, x, mzi, lsb_v, mzi_delay_s=mzi_delay_s,
                                                   mzi_lsb_v=mzi_lsb_v, mzi_q=mzi_q)
        else:
            out_f, out_det = self._plain_front_end(x, lsb_v, codes=np.asarray(beat).dtype.kind in "iu")
        if self.cw_samples:
            res = FrameResult(**pair_frame_three(self, out_f, out_det, cw_front_end(self, x, lsb_v), x))
        else:
            res = self._pair(out_f, out_det, x.shape[1])
        # a speed beyond the band the record was sized for: flagged, never valid (lidard.dsp.detect.gate)
        fast = out_of_band(res.present, res.velocity_mps, self.max_speed_mps,
                           self.wavelength_m * self.fs_hz / (2 * self.n_used))
        return keep_returns(res.refused(fast, PointFlag.OUT_OF_BAND), self.max_returns)

    def _plain_front_end(self, x: np.ndarray, lsb_v: float, codes: bool = False) -> tuple[list[Any], list[Any]]:
        """Per ramp (up, down): refined beat frequencies (n_pix, K) and detections of the range FFT.
        ``codes``: the beat came as integer ADC codes, so its volts are finite and the range FFT's
        NaN/inf pass over every sample is skipped (volts given as floats are checked)."""
        a, n, r = self.offset, self.n_used, self.ramp_samples
        rf = self.rfft
        out_f, out_det = [], []
        for r0 in (0, r):
            # the ramp's volts, (n_pix, n_avg, n_bins) spectrum and its power die with this ramp's
            # pass: one scratch buffer each for both ramps (a fresh 10 MB array faults in its pages)
            ramp = ramp_volts(x[..., r0 + a:r0 + a + n], lsb_v, iq=self.iq, down=bool(r0),
                              out=None if self.iq else scratch("frame.ramp", x.shape[:-1] + (n,), np.float64))
            shape = rf.spectrum_shape(ramp.shape[:-1])
            p = scratch("frame.power", shape, np.float64)
            spec = (rf.spectrum_of if codes else rf)(ramp, scratch("frame.spec", shape, np.complex128), p)
            def signals(idx: np.ndarray, ramp: np.ndarray = ramp,
                        spec: np.ndarray = spec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                return ramp, rf.index_to_bin(idx), spec

            res = detect_and_refine(
                spec, signals, cfar=self.cfar,
                estimator=None if self.pixel_ml else self.estimator, average_axis=1,
                idle_index=int(rf.bin_to_index(1)), power=p)
            det = res.detections
            if self.iq:     # the hybrid's image of a stronger return is not a return
                img = mirror_images(det.index, det.power, det.valid, rf.n_fft)
                det = replace(det, valid=det.valid & ~img)
            # the ramp's detections refined jointly (no mutual leakage bias), and the model-order test:
            # a peak the fitted tones do not explain hides a second surface (lidard.dsp.ranging)
            assert res.power is not None   # power=p was given
            frac, det = refine_ramp(ramp, spec, res.power, det, res.frac_bins, rf=rf,
                                    model=RampModel(self.window, self.order_level, self.ramp_pfa, self.pixel_ml,
                                                    self.max_drift_bins))
            out_f.append(frac * rf.delta_f)
            out_det.append(det)
        return out_f, out_det

    def _pair(self, out_f: list[Any], out_det: list[Any], records: int) -> FrameResult:
        """Up/down pairing by likelihood (eqs. 2-6, 2-7; :mod:`lidard.dsp.ranging.assign`), validity
        flags and the range gate."""
        du, dd = out_det
        # I/Q: the band is not a prior; a target at its edge keeps its pair (two bins of search margin)
        speed = self.max_speed_mps + (self.wavelength_m * self.rfft.delta_f if self.iq else 0.0)
        rng_m, vel, ok, match = pair_up_down_matched(
            out_f[0], out_f[1], du.valid, dd.valid, self.chirp_rate_hz_per_s, self.wavelength_m, iq=self.iq,
            max_speed_mps=speed, snr=line_snr(du, dd), records=records, tie_level=self.order_level)
        paired = (match >= 0) & du.valid
        # |X| = A/2 for a real tone, A for a complex one
        intensity = np.sqrt(du.power) * (1.0 if self.iq else 2.0)
        leak = du.valid & aliased(intensity, self.alias_ceiling_v)
        # unresolved on either ramp's peak of the pair (the pair's relative phase differs between ramps)
        unres = du.unresolved | (paired & np.take_along_axis(dd.unresolved, np.maximum(match, 0), axis=-1))
        flagged = du.harmonic | unres | leak
        valid = ok & ~flagged
        # Pairs that fold (ambiguous) or are flagged keep a range from the up ramp alone so they can be
        # drawn (valid=0).
        rng_fallback = C_M_PER_S * np.abs(out_f[0]) / (2 * self.chirp_rate_hz_per_s)
        rng_m = np.where(ok, rng_m, rng_fallback)
        present = paired & in_gate(rng_m, self.min_range_m, self.max_range_m)
        flags = point_flags(unresolved=unres, leak=leak, harmonic=du.harmonic, unpaired=~ok)
        return FrameResult(present=present, valid=valid & present, range_m=rng_m, velocity_mps=vel,
                           snr_db=du.snr_db, intensity_v=intensity, flags=flags)
