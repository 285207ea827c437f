"""The seam between the daemon/CLI and the hardware: what a scan asks for and what it gets back.

The REST API, the job queue and ``lidarctl`` only talk to an :class:`Instrument`; the real one
(``lidard.instrument.LidarInstrument``) composes the drivers and the DSP, and tests may pass a fake.
Domain objects here know nothing about HTTP.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any, Callable, Literal, Protocol

import numpy as np

PatternKind = Literal["raster", "serpentine", "roi", "pixels", "adaptive"]
OutputFormat = Literal["ply", "las", "npz"]

# One record per detected return. x, y, z in the scene's sensor frame (float32 at the file edge).
POINT_DTYPE = np.dtype([
    ("x", "f4"), ("y", "f4"), ("z", "f4"),
    ("range", "f4"),          # m, along the beam
    ("velocity", "f4"),       # m/s, radial, positive when the target recedes
    ("intensity", "f4"),      # peak amplitude, ADC volts-equivalent
    ("snr_db", "f4"),         # peak over local noise, dB (20 log10 of amplitudes)
    ("row", "u2"), ("col", "u2"),
    ("return_index", "u1"),   # 0 = first (nearest) return of that beam
    ("t", "f8"),              # s since scan start (hardware time of the pixel's first trigger)
    ("valid", "u1"),          # 0 where the DSP flagged the point (folding, harmonic, unresolved)
])


@dataclass(frozen=True)
class ScanRequest:
    pattern: PatternKind = "raster"
    rows: tuple[int, int] | None = None            # [first, stop) as for Python ranges
    cols: tuple[int, int] | None = None
    pixels: tuple[tuple[int, int], ...] | None = None
    averages: int = 1
    max_range_m: float = 2.0
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


class Instrument(Protocol):
    """What the daemon needs from the hardware (or the simulated bench)."""

    simulated: bool

    def devices(self) -> list[dict[str, Any]]:
        """Per device: name, connected, identity, state, faults."""

    def scanner(self) -> dict[str, Any]:
        """The same figures as ``lidarctl optics --json``."""

    def run_scan(self, request: ScanRequest, progress: ProgressFn, cancel: threading.Event,
                 calibration: CalibrationResult | None = None) -> ScanResult:
        """Run one scan; on cancel return the points so far with ``partial=True``."""

    def linearize(self, progress: Callable[[dict[str, Any]], None] | None = None) -> CalibrationResult:
        """Run the ILC chirp linearization through the monitor MZI."""

    def laser_temperature_c(self) -> float:
        """The laser's TEC temperature readback now (NaN when it cannot be read)."""

    def selftest(self) -> dict[str, Any]:
        """Toggle every bonded row and every column against the monitor tap; report stuck switches:
        ``{"ok": bool, "stuck": [{"line": "row"|"col", "index", "state": "on"|"off", "evidence"}],
        "single_beam_v", "partner_row", "partner_col", "rows_tested", "cols_tested", ...}``."""

    def set_scene(self, scene: dict[str, Any]) -> None:
        """Simulation only: replace the scene (raises NotImplementedError on real hardware)."""

    def close(self) -> None:
        """Bring the laser and HV down and release the devices."""
