"""Chirp linearization by iterative learning pre-distortion (dissertation §2.2; §4.4.2's monitor MZI).

The ILC itself (:func:`lidard.dsp.linearize.ilc.linearize`) is pure: it asks for measurements of a drive
waveform and learns the pre-distortion. Here each measurement is one acquisition on the centre pixel:
the drive is loaded into the AWG, the FPGA fires ``n_avg`` chirps, the digitizer records the monitor
MZI channel, and the safety monitor is checked before the samples are trusted. The ADC rate is set by
the MZI beat (chirp rate x MZI delay), not by the scan range. With a quadrature monitor
(``[monitor] quadrature``: channels ``mzi`` and ``mzi_q``) each record is the complex I + jQ and the ILC
averages per-record phases (:mod:`lidard.dsp.linearize.quadrature`), which reaches >= 1000x on the broad-linewidth
laser where the averaged real fringe fades.

Three-segment chirp: the ILC learns the two ramps as before, but each measurement plays the
whole period, the ramps followed by the held constant segment (:func:`drive_for_chirp`), so the ramps
are learned under the thermal history they will see in a scan; the record stops after the down ramp.
The constant segment is held, not learned: the laser's thermal terms keep drifting there (some
650 MHz over the hold on the sim's default DFB). Once the ramps are learned, one more acquisition of
``HOLD_AVERAGES`` whole periods measures that drift from the MZI fringe over the hold
(:func:`lidard.dsp.ranging.cwhold.hold_profile`); it is stored with the linearization (``meta["hold_profile"]``)
and the DSP takes it out of the CW beat where the real receiver's two regimes meet (|f_D| ~ f_R,
lidard.dsp.ranging.threeseg).

Region of interest (``[chirp] linear_window``, :func:`ilc_region`): ``"core"`` (the default) linearizes
the centre of each ramp (the ILC's own region: ROI 0.8, learning 0.92), ``"range"`` the whole part of
each ramp the range estimator uses (:data:`lidard.dsp.frame.RANGE_WINDOW_FRACTION`,
``FrameDsp.use_fraction``'s default: the ROI), learning ``LEARN_MARGIN`` beyond it. The range scale
of a scan is the chirp's mean slope over the range window, weighted about uniformly by the estimator.
With the core region the learned drive leaves the turnaround transient's tail, MHz-sized at 4-6 % from
a ramp end, inside the range window: a range scale of about -2.2e-5 at short range and less at long
range (the beat averages the tail over its round trip), i.e. a range error of up to 0.6 mm over 0.8-45 m
that no scale and offset absorb. The range region brings it to 0.03 mm but costs 3-4x the
linearization's CPU (the turnaround's edges are learned slowly and averaged longer), which a bench
ranging within a few metres does not need (docs/measured/26_range_linearity.md).

What it reports about its own residual (:func:`iteration_record`): per ILC measurement the RMS
nonlinearity and the RMS error against the ideal chirp of each ramp over the ROI, the periods averaged
and the measurement's noise floor; ``meta["best_iteration"]`` is the measurement of the drive kept and
``meta["learning_bandwidth_hz"]`` the bandwidth it was learned in (the Q filter). The kept drive's error
is the residual chirp error a scan inherits. On sim_far.toml (nominal bench) it is 35-42 kHz per ramp
against a noise floor of about 17 Hz: what the learning stopped improving on (mostly the turnaround's
tail at the ROI's edges), not measurement noise, so it is the same from one noise draw to the next.
tests/e2e/test_e2e_range_linearity.py turns it into the range error it allows a plate.
"""

from __future__ import annotations

import logging
from typing import Any
from collections.abc import Callable

import numpy as np

from ...config import Config
from ...dsp.frame import RANGE_WINDOW_FRACTION
from ...dsp.linearize.ilc import ChirpGeometry, IlcIteration, IlcSettings
from ...dsp.linearize.ilc import linearize as ilc_linearize
from ...dsp.ranging.cwhold import hold_profile
from ...physics.chirp import adc_rate_hz
from ..acquisition import AWG_RATE_HZ, AcquisitionLifecycle, AcquisitionPlan, drive_for_chirp
from ..errors import InstrumentError
from ..safety import SafetyMonitor, describe_safe
from ..types import CalibrationResult

log = logging.getLogger(__name__)

#: the ILC's step limit: well above what any shipped laser needs to reach its measurement noise floor
MAX_ITERATIONS = 24
#: averages per measurement may double up to this when the noise floor stops learning above the target
MAX_AVERAGES = 2048
#: periods averaged for the held segment's drift (three-segment chirp): the repeatable fringe stays,
#: the laser's phase noise and the monitor's noise average out (61 ms of hardware time at 238 us)
HOLD_AVERAGES = 256
#: the learning region reaches this far (fraction of a ramp) beyond the ROI, so the turnaround's
#: transient, which the learned drive can only shorten, settles before the range window opens
LEARN_MARGIN = 0.05


def ilc_region(linear_window: str) -> tuple[float, float]:
    """The ILC's (ROI, learning region), fractions of a ramp, for ``[chirp] linear_window``: ``"core"``
    the ILC's own centre region, ``"range"`` the range estimator's window plus ``LEARN_MARGIN``."""
    if linear_window == "core":
        return IlcSettings.roi, IlcSettings.learn
    if linear_window == "range":
        return RANGE_WINDOW_FRACTION, min(1.0, RANGE_WINDOW_FRACTION + LEARN_MARGIN)
    raise ValueError(f"chirp.linear_window must be 'core' or 'range', got {linear_window!r}")


def iteration_record(it: IlcIteration) -> dict[str, float]:
    """One ILC measurement as the linearization reports it: the RMS nonlinearity of each ramp (best line
    removed, Fig. 2-4), its RMS error against the ideal chirp (slope included, offset free: what is
    learned), the periods averaged, and the measurement's noise floor (omitted when it was not measurable,
    fewer than two periods: the report stays finite JSON)."""
    rec = {"up_rms_hz": float(it.up_rms_hz), "down_rms_hz": float(it.down_rms_hz),
           "up_error_hz": float(it.up_error_hz), "down_error_hz": float(it.down_error_hz),
           "averages": float(it.averages)}
    if np.isfinite(it.noise_floor_hz):
        rec["noise_floor_hz"] = float(it.noise_floor_hz)
    return rec


class Linearization:
    """One linearization run: ``run(plain_drive_v)`` answers the :class:`CalibrationResult`."""

    def __init__(self, cfg: Config, optics, lifecycle: AcquisitionLifecycle, safety: SafetyMonitor,
                 progress: Callable[[dict[str, Any]], None] | None = None, *, mzi_delay_s: float | None = None):
        self.cfg, self.lifecycle, self.safety, self.progress = cfg, lifecycle, safety, progress
        c = cfg.chirp
        # the ILC's target beat is chirp rate x this delay: the range calibration's effective delay
        # makes the true chirp rate the nominal one (range.py); without one, the nominal delay
        self.mzi_delay_s = cfg.monitor.delay_s if mzi_delay_s is None else float(mzi_delay_s)
        f_mzi = c.rate_hz_per_s * self.mzi_delay_s
        self.fs_hz = adc_rate_hz(1.0, c.rate_hz_per_s, max_doppler_hz=f_mzi * 2.0, oversample=4.0,
                                 max_rate_hz=cfg.adc.max_sample_rate_hz, min_rate_hz=cfg.adc.min_sample_rate_hz,
                                 ramp_s=c.ramp_s)
        self.record_length = 2 * int(round(self.fs_hz * c.ramp_s))
        rows = optics.bonded_rows
        self.centre = np.array([[rows[len(rows) // 2], optics.cols // 2]])
        self.quadrature = bool(cfg.monitor.quadrature)
        self.channels = ("mzi", "mzi_q") if self.quadrature else ("mzi",)
        self.measurements = 0
        self.hardware_s = 0.0          # trigger-to-end time of the records measured (the health check's cost)
        self.what = "linearization"    # how a safety stop names the procedure
        self.faults: dict[str, Any] = {"batch_retries": 0}

    def measure(self, drive_v: np.ndarray, n_avg: int, record_length: int | None = None) -> np.ndarray:
        """The ILC's measurement: ``n_avg`` MZI records (volts-proportional) of ``drive_v``: float64, or
        complex I + jQ with a quadrature monitor. ``record_length``: default the two ramps."""
        record_length = self.record_length if record_length is None else int(record_length)
        plan = AcquisitionPlan(self.centre, n_avg, self.channels, self.fs_hz, record_length, 16)
        acq = self.lifecycle.ready(plan, drive_v=drive_for_chirp(self.cfg, drive_v), faults=self.faults)
        self.lifecycle.start(acq)
        headers, samples = self.lifecycle.read(acq, 0, n_avg)
        self.lifecycle.stop(acq)
        if headers:
            span_ns = float(headers[-1].trigger_time_ns) - float(headers[0].trigger_time_ns)
            self.hardware_s += span_ns * 1e-9 + record_length / self.fs_hz
        reason = self.safety.check()
        if reason is not None:
            # the same safe path as a scan: outputs first, then give up the calibration
            raise InstrumentError(f"{self.what} stopped: {reason}; {describe_safe(self.safety.trip())}")
        self.measurements += 1
        if self.progress is not None:
            self.progress({"measurements": self.measurements})
        i = samples[:, acq.channel_index("mzi"), :].astype(np.float64)
        if not self.quadrature:
            return i
        return i + 1j * samples[:, acq.channel_index("mzi_q"), :]

    @property
    def region(self) -> tuple[float, float]:
        """The (ROI, learning region) this configuration linearizes over (:func:`ilc_region`): what the
        ILC learns, and what the health check measures a drive over."""
        return ilc_region(self.cfg.chirp.linear_window)

    def geometry(self) -> ChirpGeometry:
        """The chirp the linearization learns and its monitor, as the ILC and the health check see them."""
        c = self.cfg.chirp
        return ChirpGeometry(fs_drive_hz=AWG_RATE_HZ, fs_adc_hz=self.fs_hz, ramp_s=c.ramp_s,
                             excursion_hz=c.excursion_hz, mzi_delay_s=self.mzi_delay_s)

    def run(self, plain_drive_v: np.ndarray, laser: str) -> CalibrationResult:
        c = self.cfg.chirp
        # the ILC learns one triangle period (the ramps); the constant segment is appended per play
        plain_drive_v = np.asarray(plain_drive_v)[:int(round(2 * c.ramp_s * AWG_RATE_HZ))]
        self.safety.bring_up()
        try:
            roi, learn = self.region
            res = ilc_linearize(self.measure, plain_drive_v, self.geometry(),
                                IlcSettings(averages=32, max_averages=MAX_AVERAGES,
                                            max_drive_v=self.cfg.devices.awg.max_output_v,
                                            # a slow thermal term needs ~19 steps to its noise floor (measured
                                            # on the bench; the default DFB stops at ~8 by itself)
                                            max_iter=MAX_ITERATIONS, roi=roi, learn=learn))
            hold = self.measure_hold(res.drive_v) if c.shape == "three_segment" else None
        finally:
            self.safety.bring_down()
        iters = [iteration_record(it) for it in res.iterations]
        try:
            temp = float(self.safety.controller.tec_c())
        except Exception:
            temp = float("nan")
        return CalibrationResult(iterations=iters, reduction={k: float(v) for k, v in dict(res.reduction).items()},
                                 converged=bool(res.converged), laser=laser, temperature_c=temp,
                                 drive_v=drive_for_chirp(self.cfg, res.drive_v), fs_drive_hz=AWG_RATE_HZ,
                                 meta={"mzi_delay_s": self.mzi_delay_s, "adc_rate_hz": self.fs_hz,
                                       # the drive kept and the bandwidth it was learned in: with its
                                       # iteration's errors, what the residual chirp error is known to be
                                       "best_iteration": int(res.best_iteration),
                                       "learning_bandwidth_hz": float(res.meta["q_cutoff_hz"]),
                                       "monitor": "quadrature" if self.quadrature else "single MZI",
                                       **({"hold_profile": hold.as_dict()} if hold is not None else {})})

    def measure_hold(self, drive_v: np.ndarray):
        """The held segment's drift under ``drive_v`` (the learned ramps): whole-period MZI records."""
        period = int(round(self.cfg.chirp.period_s * self.fs_hz)) & ~1
        x = self.measure(drive_v, HOLD_AVERAGES, record_length=period)
        return hold_profile(x, self.fs_hz, self.record_length, self.mzi_delay_s)
