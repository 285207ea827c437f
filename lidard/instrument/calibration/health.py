"""Linearization health: is the stored chirp linearization still right for the laser as it is now?
(dissertation §2.2, the monitor MZI of §4.4.2)

A learned pre-distortion is only right for the laser it was learned on. The laser's tuning moves
with its chip temperature, and the TEC's readback does not show all of it (the thermistor is not the
chip: a gradient drifts with the ambient), so a rule on the readback temperature alone
(``scan.recalibrate_delta_c``) misses what matters. The check measures it instead: before a scan,
``scan.linearity_check_records`` periods of the drive in use are recorded on the monitor MZI (the
same measurement as one ILC iteration, :class:`.linearization.Linearization`), and their RMS error
against the ideal chirp (:func:`lidard.dsp.linearize.chirpcheck.chirp_residual`: slope excursion / ramp, free
offset), over the region the drive was linearized over (``[chirp] linear_window``,
:func:`.linearization.ilc_region`: the ROI 0.8 of each ramp by default, 0.9 with ``"range"``), is compared
with ``scan.linearity_threshold_hz``. Above it the chirp is re-linearized before
the scan (the job worker decides, :meth:`lidard.jobs.worker.ScanWorker.calibration_for_scan`).

Why the error and not the nonlinearity: a temperature change scales the FM response, which keeps a
linear chirp linear but changes its slope, and every range measured with a wrong slope is off by the
same factor (range error / range = slope error / slope). The RMS error over the ROI of a relative
slope error ``e`` is ``e x excursion x ROI / sqrt(12)`` (0.23 x 8.6 GHz x e on sim.toml), so the
default 200 kHz threshold stands for e ~ 1e-4, a range error of ~0.1 mm per metre.

Cost: one drive upload and ``linearity_check_records`` chirp periods on the centre pixel (16 x 160 us =
2.6 ms of hardware time on sim.toml), and the demodulation on the host (benchmarks/linearity_health.py).
"""

from __future__ import annotations

import time

import numpy as np

from ...config import Config
from ...dsp.linearize.chirpcheck import chirp_residual
from ..acquisition import AWG_RATE_HZ, AcquisitionLifecycle
from ..healthcheck import HealthCheck
from ..safety import SafetyMonitor
from .linearization import Linearization


class LinearizationHealth:
    """``check(drive_v)`` measures the chirp of ``drive_v`` through the monitor MZI (laser and HV up
    for the duration, as a linearization does) and answers a :class:`HealthCheck`."""

    def __init__(self, cfg: Config, optics, lifecycle: AcquisitionLifecycle, safety: SafetyMonitor, *,
                 mzi_delay_s: float | None = None):
        self.cfg, self.safety = cfg, safety
        self.records = int(cfg.scan.linearity_check_records)
        self.threshold_hz = float(cfg.scan.linearity_threshold_hz)
        # the same geometry and measurement as the ILC: centre pixel, MZI-rate ADC, one drive period;
        # and the same target: the ideal chirp is rate x the monitor delay the drive was learned
        # against (the range calibration's effective delay when there is one). Against the nominal
        # delay a calibrated drive would read (tau_eff / tau_nom - 1) x excursion off (~17 MHz for a
        # 0.7 % delay error) and every scan would re-linearize for nothing.
        self._lin = Linearization(cfg, optics, lifecycle, safety, mzi_delay_s=mzi_delay_s)
        self._lin.what = "linearization health check (before the scan)"

    def check(self, drive_v: np.ndarray) -> HealthCheck:
        c = self.cfg.chirp
        # the two ramps the ILC learns (a three-segment drive's held segment is added back by measure)
        drive_v = np.asarray(drive_v, dtype=np.float64)[:int(round(2 * c.ramp_s * AWG_RATE_HZ))]
        t0 = time.perf_counter()
        self._lin.hardware_s = 0.0
        self.safety.bring_up()
        try:
            records = self._lin.measure(drive_v, self.records)
        finally:
            self.safety.bring_down()
        # over the region the drive was linearized over ([chirp] linear_window): a drive learned over
        # the core leaves the turnaround's tail in the range window, which is not its staleness
        roi, learn = self._lin.region
        r = chirp_residual(records, drive_v, self._lin.geometry(), roi=roi, learn=learn)
        try:
            temp = float(self.safety.controller.tec_c())
        except Exception:
            temp = float("nan")
        return HealthCheck(residual_hz=r.error_hz, up_error_hz=r.up_error_hz, down_error_hz=r.down_error_hz,
                           nonlinearity_hz=max(r.up_nonlinearity_hz, r.down_nonlinearity_hz),
                           relative=r.relative, noise_floor_hz=r.noise_floor_hz, threshold_hz=self.threshold_hz,
                           records=r.records, hardware_time_s=self._lin.hardware_s,
                           wall_time_s=time.perf_counter() - t0, temperature_c=temp)

