"""The result of a linearization health check and what a scan's sidecar says about it.

Light (numpy and the standard library only) so that the job queue, which decides whether a scan
re-linearizes first (:meth:`lidard.jobs.worker.ScanWorker.calibration_for_scan`), and the API can use
it without loading the DSP. The measurement itself is :mod:`lidard.instrument.calibration.health`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

NOISE_GUARD = 3.0     # a residual within 3x the check's own noise floor is not evidence of a stale drive


@dataclass(frozen=True)
class HealthCheck:
    """One check of a drive: the RMS error (Hz) of its chirp, per ramp and overall, and the verdict."""

    residual_hz: float                  # RMS over both ramps against the ideal chirp
    up_error_hz: float
    down_error_hz: float
    nonlinearity_hz: float              # max over the ramps, best-fit line removed
    relative: float                     # residual_hz / excursion (the equivalent relative nonlinearity)
    noise_floor_hz: float               # the measurement's own noise (two halves of the records)
    threshold_hz: float
    records: int
    hardware_time_s: float              # triggers to end of the last record
    wall_time_s: float                  # upload, acquisition and analysis on the host
    temperature_c: float                # the TEC readback when checked (NaN if unreadable)

    @property
    def limit_hz(self) -> float:
        """The threshold, raised to ``NOISE_GUARD`` x the measured noise floor when the monitor is noisier
        than the threshold allows for (a broad-linewidth laser): noise alone must not re-linearize every scan."""
        noise = self.noise_floor_hz if np.isfinite(self.noise_floor_hz) else 0.0
        return max(self.threshold_hz, NOISE_GUARD * noise)

    @property
    def exceeded(self) -> bool:
        return not self.residual_hz <= self.limit_hz   # NaN (nothing measurable) counts as exceeded

    def reason(self) -> str:
        """Why this check re-linearizes (for the log and the sidecar)."""
        why = (f"{self.limit_hz / 1e3:.0f} kHz (scan.linearity_threshold_hz)" if self.limit_hz == self.threshold_hz
               else f"{self.limit_hz / 1e3:.0f} kHz ({NOISE_GUARD:g}x the check's noise floor, above "
                    f"scan.linearity_threshold_hz {self.threshold_hz / 1e3:.0f} kHz)")
        return f"linearization health: chirp error {self.residual_hz / 1e3:.0f} kHz rms above {why}"

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "limit_hz": self.limit_hz, "exceeded": self.exceeded}


def health_record(checked: HealthCheck | None, used: HealthCheck | None, reason: str | None) -> dict[str, Any] | None:
    """What a scan's sidecar says about its linearization (``linearization``): the residual of the drive
    the scan used, the threshold, whether it was re-linearized first and why. ``checked``: the check of
    the stored drive (None when there was none to check), ``used``: the check of the drive the scan ran
    with (the same check when nothing was re-linearized; None with the check off)."""
    last = used if used is not None else checked
    if last is None:
        return None if reason is None else {"relinearized": True, "reason": reason}
    out = {"residual_hz": last.residual_hz, "threshold_hz": last.threshold_hz, "limit_hz": last.limit_hz,
           "relinearized": reason is not None, "reason": reason, "relative": last.relative,
           "up_error_hz": last.up_error_hz, "down_error_hz": last.down_error_hz,
           "noise_floor_hz": last.noise_floor_hz, "records": last.records,
           "hardware_time_s": last.hardware_time_s, "temperature_c": last.temperature_c}
    if reason is not None and checked is not None:
        out["stale_residual_hz"] = checked.residual_hz      # what the stored drive showed before
    # JSON (sidecar, REST) has no NaN: an unmeasurable figure is null
    return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in out.items()}
