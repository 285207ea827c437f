"""One scan, as stages: plan -> acquire -> DSP -> points (dissertation §4.4.1 setup, §4.4.3 imaging).

* plan (:func:`plan_scan`): the pixel pattern (:mod:`lidard.instrument.plan`), the ADC rate and record length
  from the requested maximum range and the chirp (§2.1.1: beat frequency = chirp rate x round trip),
  the monitor MZI channel when phase-noise compensation is on (§2.3, §4.4.2), and the frame DSP, all
  from the one constructor a design sweep also uses (:func:`.dsp_plan.plan_signal`);
* acquire (:class:`ScanLoop`): laser and HV up, one acquisition (:mod:`.acquisition`) started, its
  segments read in batches of at most ``SAFETY_CHECK_S`` of hardware time with the safety check
  (:mod:`.safety`) after each read (the safety watch also checks on its own thread, on wall time); a lost acquisition is resumed from the first pixel not yet read
  (at most ``RESUMES`` times); a device that stays down fails the scan with :class:`ScanFailed`
  carrying the points so far;
* DSP -> points (:mod:`.points`): batches collected up to :func:`dsp_batch_bytes`, handed to the DSP's
  worker processes (:mod:`lidard.dsp_pool`, one pool per process reused by every scan; threads on one
  core) through a bounded queue (:mod:`.pipeline`; the next read goes on meanwhile), kept as points in
  pixel order.

The run's state lives in one :class:`ScanRun` context passed between the stages.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.digitizer.protocol_headers import header_column

from ..config import Config
from ..cores import pool_workers
from ..dsp.frame import FrameDsp
from ..dsp.pnframe import compensator_for, gate_m_range
from ..dsp.spectrum.jit import plan_path
from .plan import plan
from .acquisition import Acquisition, AcquisitionLifecycle, AcquisitionPlan
from .calibration.applied import AppliedCalibrations

# the signal path's one constructor; AdcPlan, adc_plan and speed_span_mps are re-exported (callers' path)
from .dsp_plan import AdcPlan, DspCalibration, adc_plan, plan_signal, speed_span_mps  # noqa: F401
from .dsp_plan import phase_noise_on as pn_rule
from .errors import ScanFailed, SegmentsLost, describe_failure, device_of, driver_error
from .points import PointBuffer, RawBatch
from .safety import SafetyMonitor, describe_safe
from .types import CalibrationResult, ProgressFn, ScanProgress, ScanRequest, ScanResult

BATCH_BYTES = 8 << 20        # raw samples per DSP batch (bounded memory)
# The smallest DSP batch a scan hands to a worker: the frame DSP's fixed cost per call shows below it
# (its sample rate falls by a third from 2 MiB to 0.5 MiB batches, benchmarks/band_and_cores.py)
DSP_MIN_BYTES = 2 << 20
# Hardware time per read: the interlock/fault flags are read between reads, so this bounds the
# host's reaction time (the controller's own hardware interlock drops the outputs at once anyway).
# Each read has a fixed cost (in the simulator mostly the FPGA model's per-call beam bookkeeping):
# 50 ms reads cost ~15-20 % of the simulated bench's throughput against unbounded reads, 10 ms ~50 %
# (benchmarks/reliability.py --tradeoff, docs/reliability.md).
SAFETY_CHECK_S = 0.05
RESUMES = 2                  # new acquisitions for the rest of a scan after one was lost

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ScanPlan:
    """Everything decided before the first trigger."""

    pixels: np.ndarray
    averages: int
    phase_noise: bool
    mzi_delay_s: float
    adc: AdcPlan
    acquisition: AcquisitionPlan
    dsp: FrameDsp
    lsb_v: float
    quadrature: bool = False            # the monitor MZI read in quadrature ("mzi_q", [monitor] quadrature)

    @property
    def n_pixels(self) -> int:
        return len(self.pixels)


def phase_noise_on(cfg: Config, request: ScanRequest, mzi_delay_s: float | None = None) -> bool:
    """Resolve scan.phase_noise_compensation (or the request's override): "auto" is on when the
    round trip of max_range_m is at least twice the monitor delay (config.ScanDefaults)."""
    return pn_rule(request.phase_noise_compensation or cfg.scan.phase_noise_compensation,
                   float(request.max_range_m), mzi_delay_s or cfg.monitor.delay_s)


def plan_scan(cfg: Config, optics, request: ScanRequest, mzi_delay_s: float | None = None,
              iq_imbalance: tuple[float, float] = (1.0, 0.0), hold_profile: dict | None = None) -> ScanPlan:
    """``mzi_delay_s``: the range calibration's effective monitor delay (default: the nominal one);
    ``iq_imbalance``: the I/Q calibration's (gain ratio, phase error) the DSP removes (adc.iq);
    ``hold_profile``: the linearization's measured drift of the held segment (three-segment chirp)."""
    pixels = plan(request, optics)
    avg = int(request.averages)
    tau_m = cfg.monitor.delay_s if mzi_delay_s is None else float(mzi_delay_s)
    sig = plan_signal(cfg, DspCalibration(tau_m, iq_imbalance[0], iq_imbalance[1], hold_profile),
                      max_range_m=request.max_range_m, max_speed_mps=request.max_speed_mps,
                      phase_noise=request.phase_noise_compensation)
    adc, pn_on, quad = sig.adc, sig.phase_noise, sig.quadrature
    beat = ("beat_i", "beat_q") if cfg.adc.iq else ("beat",)
    channels = beat + (("mzi", "mzi_q") if quad else ("mzi",) if pn_on else ())
    acq = AcquisitionPlan(pixels, avg, channels, adc.fs_hz, adc.record_length, adc.bits)
    return ScanPlan(pixels, avg, pn_on, tau_m, adc, acq, sig.dsp, cfg.adc.input_range_v / 2 ** adc.bits, quad)


def pixel_bytes(p: ScanPlan) -> int:
    """Raw bytes a pixel's segments take (every channel)."""
    return p.averages * p.adc.record_length * (1 if p.adc.bits == 8 else 2) * len(p.acquisition.channels)


def batch_pixels(cfg: Config, p: ScanPlan) -> int:
    """Pixels per read: bounded by BATCH_BYTES of raw samples and SAFETY_CHECK_S of hardware time."""
    bytes_per_pix = pixel_bytes(p)
    pixel_s = p.averages * cfg.chirp.period_s + cfg.scan.settle_s
    return max(1, min(p.n_pixels, BATCH_BYTES // max(1, bytes_per_pix), int(SAFETY_CHECK_S / pixel_s)))


def dsp_batch_bytes(p: ScanPlan, workers: int) -> int:
    """Raw bytes per DSP batch: a few batches per worker over the scan, so that reads and DSP overlap
    from the start, within [DSP_MIN_BYTES, BATCH_BYTES]."""
    return int(min(BATCH_BYTES, max(DSP_MIN_BYTES, p.n_pixels * pixel_bytes(p) // (2 * workers + 2))))


def uses_dsp_processes(p: ScanPlan, workers: int) -> bool:
    """Whether a scan of ``p`` hands its batches to the DSP's worker processes: more than one batch
    (one batch has nothing to overlap) on a process that may use more than one core."""
    return workers >= 2 and p.n_pixels * pixel_bytes(p) > dsp_batch_bytes(p, workers)


@dataclass
class ScanRun:
    """The state of one scan between its stages (what used to live in closures and cells)."""

    plan: ScanPlan
    points: PointBuffer
    calibration_id: Any = None
    done: int = 0                       # pixels read and accepted
    hw_t0_ns: float | None = None       # trigger time of the current acquisition's scan start
    hw_last_s: float = 0.0              # hardware time at the end of the last pixel read
    t_shift_s: float = 0.0              # where a resumed acquisition's clock continues
    cancelled: bool = False
    stop_reason: str | None = None
    safe: dict[str, Any] | None = None  # readbacks of a safety stop (outputs already down)
    raw: Any = None                     # lidard.raw.record.ScanRecorder when the scan records raw segments
    faults: dict[str, Any] = field(default_factory=lambda: {"batch_retries": 0, "resumes": 0,
                                                            "overrange_segments": 0, "overrange_pixels": 0})


class ScanLoop:
    """Runs one scan plan over the acquisition lifecycle with the safety monitor between reads."""

    def __init__(self, cfg: Config, optics, lifecycle: AcquisitionLifecycle, safety: SafetyMonitor, *,
                 simulated: bool):
        self.cfg, self.optics, self.lifecycle, self.safety = cfg, optics, lifecycle, safety
        self.simulated = simulated
        self.applied = AppliedCalibrations()   # the facade's use_calibrations sets it

    def run(self, request: ScanRequest, progress: ProgressFn, cancel: threading.Event, drive_v: np.ndarray,
            calibration: CalibrationResult | None = None, raw_path=None) -> ScanResult:
        """``raw_path``: also record every accepted batch of segments there (:mod:`lidard.raw`)."""
        p = plan_scan(self.cfg, self.optics, request, self.applied.delay_or(self.cfg.monitor.delay_s),
                      self.applied.iq_imbalance, (calibration.meta or {}).get("hold_profile") if calibration else None)
        progress(ScanProgress(0, p.n_pixels, 0, 0.0, stage="preparing"))
        workers = pool_workers()
        run = self.new_run(p, (calibration.meta or {}).get("id") if calibration else None,
                           flush_bytes=dsp_batch_bytes(p, workers), workers=workers,
                           processes=uses_dsp_processes(p, workers), replayed=raw_path is not None)
        try:
            self.safety.bring_up()
            try:
                acq = self.lifecycle.ready(p.acquisition, drive_v=drive_v, faults=run.faults)
                if raw_path is not None:   # the digitizer has told its channel order: the records' layout
                    run.raw = self._recorder(raw_path, run, acq, request, drive_v)
                self.lifecycle.start(acq)
                step = batch_pixels(self.cfg, p)
                while run.done < p.n_pixels and run.stop_reason is None:
                    if cancel.is_set():
                        run.cancelled = True
                        break
                    acq, accepted = self.step(run, acq, min(step, p.n_pixels - run.done))
                    if accepted:
                        progress(ScanProgress(run.done, p.n_pixels, run.points.count, run.hw_last_s,
                                              new_points=run.points.take_new()))
                if run.stop_reason is None and self.safety.tripped is not None:
                    self.safety_stop(run)      # the wall-clock watch tripped after the last read's check
            except ScanFailed:
                raise
            except Exception as exc:
                raise ScanFailed(describe_failure(exc), self.result(run)) from driver_error(exc)
            finally:
                self._finish(run)
                if run.raw is not None:
                    run.raw.close(pixels_scanned=run.done, stop_reason=run.stop_reason)
            return self.result(run)
        finally:
            run.points.close()      # the DSP workers end on every path (after result(): nothing left)

    def new_run(self, p: ScanPlan, calibration_id: Any = None, *, flush_bytes: int, workers: int = 0,
                processes: bool = False, dsp_path: str | None = None, replayed: bool = False) -> ScanRun:
        """The context of one run of ``p``: its points computed with the calibrations in use, on one
        DSP path (``dsp_path``, else decided for the run's planned pixels: lidard.dsp.spectrum.jit).
        ``replayed``: the run records its raw segments, whose replays follow the path it takes, so a
        replay's cells count in its decision too."""
        points = PointBuffer(p.dsp, self.applied.optics(self.optics), lsb_v=p.lsb_v, mzi_delay_s=p.mzi_delay_s,
                             flush_bytes=flush_bytes, zero_offset_m=self.applied.zero_offset_m, workers=workers,
                             processes=processes)
        # decided once it is known where the batches run (the pool's workers have the kernels loaded)
        cells = p.dsp.spectrum_cells(p.n_pixels, p.averages) * (1 + replayed)
        points.set_path(dsp_path or plan_path(cells, preloaded=points.pooled))
        return ScanRun(p, points, calibration_id=calibration_id)

    def _recorder(self, raw_path, run: ScanRun, acq: Acquisition, request: ScanRequest, drive_v: np.ndarray):
        from ..raw.record import (  # zarr is loaded only by scans that record
            RecordLayout,
            ReplayRecipe,
            ScanDescription,
            ScanRecorder,
        )
        p, adc = run.plan, run.plan.adc
        optics = self.applied.optics(self.optics)      # the calibrated rays, as the points use
        return ScanRecorder.start(
            raw_path,
            RecordLayout(pixels=p.pixels, directions=optics.directions(p.pixels[:, 0], p.pixels[:, 1]),
                         averages=p.averages, channels=tuple(acq.layout.channels), record_length=adc.record_length),
            ReplayRecipe(dsp=p.dsp, lsb_v=p.lsb_v, phase_noise=p.phase_noise, mzi_delay_s=p.mzi_delay_s,
                         dsp_path=run.points.dsp_path),
            ScanDescription(
                adc={"sample_rate_hz": adc.fs_hz, "record_length": adc.record_length, "bits": adc.bits,
                     "ramp_samples": adc.ramp_samples, "input_range_v": self.cfg.adc.input_range_v},
                chirp=self.cfg.chirp.model_dump(), calibration_id=run.calibration_id,
                scan={"pattern": request.pattern, "averages": p.averages, "max_range_m": float(request.max_range_m),
                      "max_speed_mps": float(p.dsp.max_speed_mps)}),
            drive_v=drive_v)

    # -- acquire ----------------------------------------------------------------------------------
    def step(self, run: ScanRun, acq: Acquisition, bp: int) -> tuple[Acquisition, bool]:
        """Read the next ``bp`` pixels, check safety, hand them on. Answers the acquisition to go on
        with and whether the pixels were accepted (not after a safety stop or a resume).

        Public with :meth:`new_run` and :meth:`safety_stop`: a stream (:mod:`.stream`) runs its frames
        on the same read / check / DSP step as a scan, only the sequencing differs."""
        avg = run.plan.averages
        try:
            headers, samples = self.lifecycle.read(acq, (run.done - acq.first_pixel) * avg, bp * avg)
        except SegmentsLost as exc:
            # before blaming the digitizer: did the interlock or a fault stop the light?
            if self.safety_stop(run):
                return acq, False
            return self._resume(run, acq, exc), False
        if self.safety_stop(run):
            # Outputs first; the batch in flight is discarded (when the light went is unknown).
            run.faults["discarded_pixels"] = bp
            log.warning("scan stopped after %d of %d pixels: %s", run.done, run.plan.n_pixels, run.stop_reason)
            return acq, False
        self._accept(run, acq, headers, samples, bp)
        return acq, True

    def safety_stop(self, run: ScanRun) -> bool:
        """Trip the safe state when the safety check (or the wall-clock watch) says so; the run keeps
        the readbacks and the reason. Answers whether it stopped."""
        reason = self.safety.check()        # the watch's reason once it tripped, else the flags
        if reason is None:
            return False
        run.safe = self.safety.trip(reason)
        run.stop_reason = f"{reason}; {describe_safe(run.safe)}"
        return True

    def _resume(self, run: ScanRun, acq: Acquisition, exc: SegmentsLost) -> Acquisition:
        if run.faults["resumes"] >= RESUMES:
            raise ScanFailed(str(exc), self.result(run)) from exc
        # The acquisition itself is lost (a replugged digitizer resets it): run the rest of the
        # pattern as a new acquisition from the first pixel not yet read.
        run.faults["resumes"] += 1
        log.warning("scan: resuming from pixel %d of %d after %s", run.done, run.plan.n_pixels, exc)
        try:
            acq = self.lifecycle.restart(acq, run.done)
        except Exception as exc2:
            cause = driver_error(exc2)
            raise ScanFailed(f"{device_of(exc2)}: resume after '{exc}' failed: {type(cause).__name__}: {cause}",
                             self.result(run)) from cause
        run.t_shift_s = run.hw_last_s
        run.hw_t0_ns = None
        return acq

    def _accept(self, run: ScanRun, acq: Acquisition, headers: list, samples: np.ndarray, bp: int) -> None:
        p = run.plan
        avg, rl = p.averages, p.adc.record_length
        t_ns = header_column(headers, "trigger_time_ns").astype(np.float64)
        if run.hw_t0_ns is None:
            # after a resume the new run's clock continues where the last pixel read ended
            run.hw_t0_ns = t_ns[0] - run.t_shift_s * 1e9
        iq = p.dsp.iq
        beat = samples[:, acq.channel_index("beat_i" if iq else "beat"), :].reshape(bp, avg, rl)
        beat_q = samples[:, acq.channel_index("beat_q"), :].reshape(bp, avg, rl) if iq else None
        mzi = samples[:, acq.channel_index("mzi"), :].reshape(bp, avg, rl) if p.phase_noise else None
        mzi_q = samples[:, acq.channel_index("mzi_q"), :].reshape(bp, avg, rl) if p.quadrature else None
        # a clipped beat puts harmonics and a wrong amplitude into the spectrum
        over = header_column(headers, "overrange").reshape(bp, avg) != 0
        clipped = over.any(axis=1)
        run.faults["overrange_segments"] += int(over.sum())
        run.faults["overrange_pixels"] += int(clipped.sum())
        t_pix = (t_ns.reshape(bp, avg)[:, 0] - run.hw_t0_ns) * 1e-9
        if run.raw is not None:
            run.raw.add(samples, headers, t_pix, acq.layout.channels)
        batch = RawBatch(beat, p.pixels[run.done:run.done + bp], t_pix, clipped, mzi, mzi_q, beat_q)
        run.done += bp
        run.hw_last_s = (t_ns[-1] - run.hw_t0_ns) * 1e-9 + rl / p.adc.fs_hz
        run.points.add(batch, last=run.done >= p.n_pixels)

    def _finish(self, run: ScanRun) -> None:
        """Stop the FPGA, abort an unfinished acquisition, bring the outputs down (each step runs even
        when the one before fails). After a safety stop the outputs are already down."""
        early = run.done < run.plan.n_pixels
        if run.safe is not None:
            self.safety.stop_watch()
            try:
                self.lifecycle.stop()
            except Exception as exc:  # outputs are already safe; report, do not mask the stop
                log.warning("fpsa stop after a safety stop failed: %s", exc)
            if early:
                self.lifecycle.abort()
            return
        try:
            self.lifecycle.stop()
        finally:
            try:
                if early:
                    self.lifecycle.abort()
            finally:
                self.safety.bring_down()

    # -- result -----------------------------------------------------------------------------------
    def result(self, run: ScanRun) -> ScanResult:
        points = run.points.points()
        return ScanResult(points=points, meta=self._meta(run), pixels_scanned=run.done,
                          pixels_planned=run.plan.n_pixels, hardware_time_s=run.hw_last_s,
                          partial=run.cancelled or run.stop_reason is not None, stop_reason=run.stop_reason)

    def _meta(self, run: ScanRun) -> dict[str, Any]:
        p, dsp, adc = run.plan, run.plan.dsp, run.plan.adc
        meta: dict[str, Any] = {
            "adc": {"sample_rate_hz": adc.fs_hz, "record_length": adc.record_length, "bits": adc.bits,
                    # the resolution asked of the digitizer (core bits + decimation gain + guard bits)
                    "resolution_bits": self.cfg.adc.record_bits(adc.fs_hz, adc.bits),
                    "bandwidth_hz": self.cfg.adc.bandwidth_hz,
                    "ramp_samples": adc.ramp_samples, "input_range_v": self.cfg.adc.input_range_v,
                    # the Doppler band the rate was sized for (the request's max_speed_mps): a faster
                    # target's beat lies outside it and is flagged, never ranged
                    "max_speed_mps": dsp.max_speed_mps,
                    "doppler_band_hz": 2 * dsp.max_speed_mps / dsp.wavelength_m},
            "dsp": dsp.sidecar(p.phase_noise, run.points.dsp_path),
            "simulated": self.simulated,
            "calibration_id": run.calibration_id,
            "faults": dict(run.faults),
            # the range / pointing calibrations the ranges and directions were computed with
            "geometry": self.applied.meta(self.cfg.monitor.delay_s, float(dsp.max_range_m)),
            "calibrated": self.applied.calibrated(run.calibration_id is not None, iq=p.dsp.iq),
        }
        if p.phase_noise:
            comp = compensator_for(dsp, p.mzi_delay_s)
            meta["dsp"]["phase_noise"] = {
                "mzi_delay_s": p.mzi_delay_s, "mzi_beat_hz": comp.mzi_beat_hz, "m_max": comp.m_max,
                # nearest M of the bins inside the range gate (0 = uncompensated near ranges)
                "m_range": list(gate_m_range(dsp, p.mzi_delay_s)),
                # quadrature: every bin at its own round trip, to the grid step; single MZI: nearest M tau_m
                "method": "quadrature" if p.quadrature else "single MZI",
                "tau_step_s": comp.step_s if p.quadrature else p.mzi_delay_s}
        if run.raw is not None:
            meta["raw"] = {"pixels": run.raw.pixels_recorded, "error": run.raw.error}
        if run.safe is not None:
            meta["safe_state"] = run.safe
        if run.stop_reason is not None:
            meta["stop_reason"] = run.stop_reason
        return meta
