"""What a scan asks for and what it gets back: the domain objects at the instrument's seam.

The REST API, the job queue and ``lidarctl`` talk to an instrument only through
:class:`lidard.instrument.protocol.Instrument` and these objects; they know nothing about HTTP. The
point record follows the outputs of dissertation §4.4 (range, radial velocity and intensity per
beam: the 3D imaging of §4.4.3); the calibration result is the chirp linearization of §2.2.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal
from collections.abc import Callable

import numpy as np

# One record per detected return: the schema of lidard.outputs.schema (name, dtype, unit, meaning of each
# field), the same in memory and in every file format.
from ..outputs.schema import POINT_DTYPE  # noqa: F401  (re-exported: the seam's point record)
from ..outputs.registry import PointFormat

PatternKind = Literal["raster", "serpentine", "roi", "pixels", "adaptive", "track"]  # track: streams only
OutputFormat = PointFormat  # the one list of point-file formats (lidard.outputs.registry)



@dataclass(frozen=True)
class ScanRequest:
    pattern: PatternKind = "raster"
    rows: tuple[int, int] | None = None            # [first, stop) as for Python ranges
    cols: tuple[int, int] | None = None
    pixels: tuple[tuple[int, int], ...] | None = None
    averages: int = 1
    max_range_m: float = 2.0
    # the fastest radial speed to measure (sizes the ADC's Doppler band); None: scan.max_speed_mps
    max_speed_mps: float | None = None
    formats: tuple[OutputFormat, ...] = ("ply",)
    # None: the configuration's scan.phase_noise_compensation ("auto" | "on" | "off")
    phase_noise_compensation: Literal["auto", "on", "off"] | None = None
    # keep the digitizer's raw segments (lidard.raw) where the caller of run_scan says (raw_path)
    record_raw: bool = False


@dataclass
class ScanProgress:
    pixels_done: int
    pixels_planned: int
    points: int
    hardware_time_s: float
    stage: str = "scanning"      # "preparing" | "linearizing" | "scanning" | "finishing"
    # the points processed since the previous report (live viewers, Foxglove); None: none new
    new_points: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def fraction(self) -> float:
        return 0.0 if self.pixels_planned == 0 else self.pixels_done / self.pixels_planned


@dataclass
class ScanResult:
    points: np.ndarray                               # POINT_DTYPE records
    meta: dict[str, Any]                             # JSON sidecar content (profile, chirp, adc, ...)
    pixels_scanned: int
    pixels_planned: int
    hardware_time_s: float
    partial: bool = False                            # cancelled / interlock / fault part-way
    stop_reason: str | None = None                   # why a scan stopped early (interlock, fault)


@dataclass
class CalibrationResult:
    iterations: list[dict[str, float]]               # [{up_rms_hz, down_rms_hz, ...}, ...]
    reduction: dict[str, float]                      # {up, down}
    converged: bool
    laser: str
    temperature_c: float
    drive_v: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    fs_drive_hz: float = 0.0
    meta: dict[str, Any] = field(default_factory=dict)


class ScanCancelled(Exception):
    """Raised inside a scan when its cancel event is set; the engine keeps the points so far."""


ProgressFn = Callable[[ScanProgress], None]
