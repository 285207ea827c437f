"""The :class:`Instrument` protocol: exactly what the REST routers, the job worker and ``lidarctl`` call.

The real instrument (:class:`lidard.instrument.facade.LidarInstrument`) and the tests' fakes both
satisfy it, so callers use plain attribute access (no ``getattr``/``hasattr`` probing). Simulation
control is part of it: on real hardware those methods raise :class:`NotSimulated`, which the API
answers with 409. The operations follow dissertation §4.4.1 (scans), §2.2 (chirp linearization) and
§4.3.3 (the FPSA's row/column switch control, which the self-test toggles).
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable
from collections.abc import Callable

from .healthcheck import HealthCheck
from .types import CalibrationResult, ProgressFn, ScanRequest, ScanResult

if TYPE_CHECKING:   # the seam stays free of the calibration rooms at run time
    from .calibration.applied import AppliedCalibrations
    from .frames import Frame, Planner, StreamResult

StageFn = Callable[[dict[str, Any]], None]


@runtime_checkable
class Instrument(Protocol):
    """What the daemon needs from the hardware (or the simulated bench)."""

    simulated: bool

    def devices(self) -> list[dict[str, Any]]:
        """Per device: name, connected, identity, state, faults."""

    def scanner(self) -> dict[str, Any]:
        """The same figures as ``lidarctl optics --json``."""

    def run_scan(self, request: ScanRequest, progress: ProgressFn, cancel: threading.Event,
                 calibration: CalibrationResult | None = None, raw_path: Path | None = None) -> ScanResult:
        """Run one scan; on cancel return the points so far with ``partial=True``. With ``raw_path``
        the digitizer's raw segments are recorded there (lidard.raw; the job queue passes it only for
        a request with ``record_raw``)."""

    def run_stream(self, request: ScanRequest, planner: Planner, on_frame: Callable[[Frame], None],
                   cancel: threading.Event, calibration: CalibrationResult | None = None, *,
                   frames: int | None = None, health_interval_s: float = 60.0,
                   on_points: Callable[[Any], None] | None = None) -> StreamResult:
        """Frames back to back over one bring-up (:mod:`lidard.instrument.stream`): ``planner(k,
        history)`` says which pixels frame ``k`` visits, each finished (or the partial last) frame goes
        to ``on_frame`` as soon as it is complete, until ``frames`` are done or ``cancel`` is set; the
        linearization health check is repeated between frames when the TEC or ``health_interval_s``
        of hardware time says so."""

    def linearize(self, progress: StageFn | None = None) -> CalibrationResult:
        """Run the ILC chirp linearization through the monitor MZI."""

    def check_linearization(self, calibration: CalibrationResult | None) -> HealthCheck | None:
        """The linearization health check of the drive a scan with ``calibration`` would use: its chirp
        measured through the monitor MZI against the ideal; None when the check is off."""

    def use_calibrations(self, applied: AppliedCalibrations) -> None:
        """Use these range/pointing calibrations (effective monitor delay, zero offset, pointing) for the
        following linearizations and scans (the job worker hands the newest stored ones over)."""

    def monitor_delay_s(self) -> float:
        """The monitor delay a linearization now targets (range-calibrated, else nominal)."""

    def laser_temperature_c(self) -> float:
        """The laser's TEC temperature readback now (NaN when it cannot be read)."""

    def selftest(self, progress: StageFn | None = None) -> dict[str, Any]:
        """Toggle every bonded row and every column against the monitor tap; report stuck switches:
        ``{"ok": bool, "stuck": [{"line": "row"|"col", "index", "state": "on"|"off", "evidence"}],
        "single_beam_v", "partner_row", "partner_col", "rows_tested", "cols_tested", ...}``."""

    def controller_faults(self) -> dict[str, Any]:
        """``{"latched": [fault names], "interlock_closed": bool}`` of the laser/HV controller now."""

    def acknowledge_faults(self, by: str) -> dict[str, Any]:
        """Clear the controller's latched faults when their causes are gone; answers ``{"cleared":
        [names], "by": by, "at": unix time}``, else raises FaultsStillOpen naming what is still open."""

    def expect_scan(self, request: ScanRequest) -> bool:
        """A scan of ``request`` is coming (a one-shot command, before anything else has run): start
        what it will need (the DSP's worker processes; a simulated bench's compiled kernels) beside the
        caller's set-up; answers whether anything was started."""

    def set_scene(self, scene: dict[str, Any]) -> dict[str, Any]:
        """Simulation only: replace the scene; returns ``{"name", "targets"}``. A scene the bench
        refuses raises a ``ValueError`` naming what is wrong; real hardware raises NotSimulated."""

    def inject_fault(self, kind: str, **params: Any) -> dict[str, Any]:
        """Simulation only: inject a bench fault; returns it with its ``id``. A refused fault raises
        a ``ValueError`` (SimFaultError) naming it; real hardware raises NotSimulated."""

    def clear_faults(self, kind: str | None = None) -> int:
        """Simulation only: clear every fault (or those of ``kind``); returns how many."""

    def active_faults(self) -> list[dict[str, Any]]:
        """Simulation only: the faults now active on the bench."""

    def close(self) -> None:
        """Bring the laser and HV down and release the devices."""


#: The names callers may use on an instrument (what a fake must provide; checked in the tests).
INSTRUMENT_MEMBERS = ("simulated", "devices", "scanner", "run_scan", "run_stream", "linearize",
                      "check_linearization", "use_calibrations", "monitor_delay_s", "laser_temperature_c",
                      "selftest", "controller_faults", "acknowledge_faults", "expect_scan", "set_scene", "inject_fault",
                      "clear_faults", "active_faults", "close")
