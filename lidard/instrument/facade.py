"""The instrument facade: what the job worker, the REST API and ``lidarctl`` call (dissertation §4.4).

:class:`LidarInstrument` is the one object that owns the hardware of §4.4.1 (the job worker calls it
from one thread; a lock keeps callers apart). It holds the rooms and delegates:

* scans -> :mod:`.scan_loop` (plan -> acquire -> DSP -> points, §4.4.3 imaging);
* chirp linearization and its health check before each scan -> :mod:`.calibration` (§2.2); the range
  and pointing calibrations it is handed (``use_calibrations``: effective monitor delay, zero offset,
  pointing) shape the linearization's target and every scan's ranges and directions;
* the switch self-test -> :mod:`.selftest` (the FPSA's row/column lines, §4.3.3);
* interlock, faults and the outputs -> :mod:`.safety`;
* the four devices -> :mod:`.devices` (one registry: identities, GET /devices health and reconnect);
* simulation control (scene, bench faults) -> the :class:`SimHooks` the composition root
  (:mod:`.compose`) hands over for a simulated bench; on real hardware it raises :class:`NotSimulated`.

Faults (docs/reliability.md): drivers retry their own transfers; the acquisition re-reads a
failed batch of segments and resumes a lost acquisition; a device that stays down fails the scan with
:class:`ScanFailed` naming the device (the points so far ride on it); the interlock and latched faults
are checked between reads and trip the safe state (laser and HV off first, read back).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any
from collections.abc import Callable

import numpy as np

from ..config import Config
from ..cores import pool_workers
from ..dsp_pool import warm_in_background
from .acquisition import AcquisitionLifecycle, drive_for_chirp, plain_drive
from .calibration.applied import AppliedCalibrations
from .calibration.health import HealthCheck, LinearizationHealth
from .calibration.linearization import Linearization
from .devices import DeviceRegistry
from .errors import NotSimulated, SimFaultError
from .errors import on_device
from .frames import Frame, Planner, StreamResult
from .safety import FaultsStillOpen, SafetyMonitor, acknowledge, latched_state
from .scan_loop import ScanLoop, plan_scan, uses_dsp_processes
from .selftest import run_selftest
from .types import CalibrationResult, ProgressFn, ScanRequest, ScanResult

DEVICES_WAIT_S = 0.5         # GET /devices waits this long for the instrument before answering "busy"

log = logging.getLogger(__name__)


@dataclass
class SimHooks:
    """What the composition root gives the instrument to reach a simulated bench."""

    set_scene: Callable[[dict], dict]
    inject_fault: Callable[..., dict]
    clear_faults: Callable[[str | None], int]
    active_faults: Callable[[], list]
    #: the bench's ledger of modelled / skipped effects (cumulative counts of captured batches)
    fidelity: Callable[[], dict] | None = None
    #: hold the scene's clock across runs (a stream's frames share the scene time of its first trigger)
    hold_scene_clock: Callable[[bool], object] | None = None
    #: a scan of this many record samples is coming: the bench prepares what it will need (its kernels)
    expect_scan: Callable[[int], bool] | None = None


class LidarInstrument:
    """Scans, calibration, self-test, device health and simulation control over one set of drivers."""

    def __init__(self, cfg: Config, drivers: DeviceRegistry, *, simulated: bool,
                 sleep: Callable[[float], object] = time.sleep, on_close: Callable[[], None] | None = None,
                 now: Callable[[], float] = time.monotonic, sim: SimHooks | None = None):
        """``drivers``: the four devices' drivers (:func:`lidard.instrument.compose.open_instrument`
        connects them); identified here, the FPSA's registers cleared."""
        self.cfg = cfg
        self.profile = cfg.resolved.profile
        self.laser = cfg.resolved.laser
        self.optics = self.profile.optics(cfg.lens, cfg.chirp.wavelength_m)
        self.registry = drivers
        controller, fpsa = drivers["controller"], drivers["fpsa"]
        self.simulated = simulated
        self._sleep = sleep
        self._sim = sim
        self._on_close = on_close
        self._lock = threading.RLock()
        self._last_devices: list[dict[str, Any]] = []
        self.safety = SafetyMonitor(controller, laser_current_ma=cfg.devices.controller.laser_current_ma,
                                    hv_v=self.profile.actuation_v, sleep=sleep, now=now,
                                    period_s=cfg.daemon.safety_period_s,
                                    pull_in_v=self.profile.pull_in_v, spread_v=self.profile.threshold_spread_v)
        self.acquisition = AcquisitionLifecycle(self.registry, cfg, sleep)
        self.scan_loop = ScanLoop(cfg, self.optics, self.acquisition, self.safety, simulated=simulated)
        self.applied = AppliedCalibrations()   # range / pointing calibrations in use
        self.registry.identify_all()
        # The HV583 registers power up with random contents (ghost beams): clear them first.
        try:
            fpsa.reset()
        except Exception as exc:
            self.registry.identity["fpsa"] = f"reset failed: {exc}"

    # The drivers by name (tests and benchmarks reach them as inst.fpsa, inst.digitizer, ...).
    @property
    def fpsa(self) -> Any:
        return self.registry["fpsa"]

    @property
    def awg(self) -> Any:
        return self.registry["awg"]

    @property
    def digitizer(self) -> Any:
        return self.registry["digitizer"]

    @property
    def controller(self) -> Any:
        return self.registry["controller"]

    # -- information ----------------------------------------------------------------------------------
    def laser_temperature_c(self) -> float:
        with self._lock:
            try:
                return float(self.controller.tec_c())
            except Exception as exc:   # the caller decides what an unknown temperature means
                log.warning("controller: TEC temperature unreadable: %s", exc)
                return float("nan")

    def devices(self) -> list[dict[str, Any]]:
        """Per device: connected true/false and the cause. A device that does not answer is
        reconnected once (serial port reopened, USB device re-found, Modbus reconnected) and asked
        again, so GET /devices both shows and heals a lost connection."""
        # The drivers are not thread-safe, so the checks need the instrument; while a scan holds it,
        # answer from the last check instead of blocking the caller for the whole scan.
        if not self._lock.acquire(timeout=DEVICES_WAIT_S):
            # ``busy``: the entry is the last check, the device is in use by the running job
            return [{**e, "busy": True, "reconnected": False}
                    for e in self._last_devices] or self.registry.busy_listing()
        try:
            self._last_devices = self.registry.check_all()
            return self._last_devices
        finally:
            self._lock.release()

    def controller_faults(self) -> dict[str, Any]:
        """The controller's latched faults and interlock now (no instrument lock: the driver
        serializes its requests, so this answers while a scan runs)."""
        with on_device("controller", "read faults"):
            return latched_state(self.controller)

    def acknowledge_faults(self, by: str) -> dict[str, Any]:
        """Clear the latched faults whose cause is gone (else :class:`FaultsStillOpen`); logged with
        who and when. Answers ``{"cleared": [names], "by": by, "at": unix time}``."""
        with on_device("controller", "acknowledge faults"):
            try:
                cleared = acknowledge(self.controller)
            except FaultsStillOpen as exc:
                log.warning("controller faults NOT acknowledged (asked by %s): %s", by, exc)
                raise
        at = time.time()
        log.warning("controller faults acknowledged by %s at %s: %s", by,
                    time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(at)), ", ".join(cleared) or "none latched")
        return {"cleared": cleared, "by": by, "at": at}

    def scanner(self) -> dict[str, Any]:
        return self.optics.summary()

    # -- scans, calibration, self-test -----------------------------------------------------------------
    def _plain_drive(self) -> np.ndarray:
        return plain_drive(self.cfg, self.laser.static_tuning_hz_per_v)

    def _load_drive(self, drive_v: np.ndarray) -> None:
        self.acquisition.load_drive(drive_v)

    def run_scan(self, request: ScanRequest, progress: ProgressFn, cancel: threading.Event,
                 calibration: CalibrationResult | None = None, raw_path=None) -> ScanResult:
        with self._lock:
            drive = (drive_for_chirp(self.cfg, calibration.drive_v)
                     if (calibration is not None and calibration.drive_v.size) else self._plain_drive())
            before = self._fidelity()
            result = self.scan_loop.run(request, progress, cancel, drive, calibration, raw_path=raw_path)
            after = self._fidelity()
            if before is not None and after is not None:
                result.meta["sim"] = {"fidelity": _ledger_difference(after, before)}
            return result

    def run_stream(self, request: ScanRequest, planner: Planner, on_frame: Callable[[Frame], None],
                   cancel: threading.Event, calibration: CalibrationResult | None = None, *,
                   frames: int | None = None, health_interval_s: float = 60.0,
                   on_points: Callable[[Any], None] | None = None) -> StreamResult:
        """Frames back to back over one bring-up (:mod:`.stream`); the linearization health check is
        repeated between frames when the TEC or ``health_interval_s`` says so."""
        from .stream import StreamLoop
        with self._lock:
            drive = (drive_for_chirp(self.cfg, calibration.drive_v)
                     if (calibration is not None and calibration.drive_v.size) else self._plain_drive())
            health = None
            if self.cfg.scan.linearity_check:
                health = lambda: LinearizationHealth(self.cfg, self.optics, self.acquisition,  # noqa: E731
                                                     self.safety).check(drive)
            loop = StreamLoop(self.scan_loop, health=health, tec=lambda: float(self.controller.tec_c()),
                              scene_clock=self._sim.hold_scene_clock if self._sim is not None else None)
            return loop.run(request, planner, on_frame, cancel, drive, calibration, frames=frames,
                            health_interval_s=health_interval_s, on_points=on_points)

    def _fidelity(self) -> dict[str, Any] | None:
        """The simulated bench's ledger of modelled / skipped effects (None on real hardware)."""
        if self._sim is None or self._sim.fidelity is None:
            return None
        return self._sim.fidelity()

    def use_calibrations(self, applied: AppliedCalibrations) -> None:
        """Use these range/pointing calibrations for the following linearizations and scans."""
        with self._lock:
            self.applied = applied
            self.scan_loop.applied = applied

    @property
    def iq_receiver(self) -> bool:
        """The beat arrives from a coherent (I/Q) receiver (adc.iq): its imbalance calibration applies."""
        return bool(self.cfg.adc.iq)

    def monitor_delay_s(self) -> float:
        """The monitor delay the linearization targets now: the range calibration's effective delay, or
        the configuration's nominal ``monitor.delay_s`` without one."""
        return self.applied.delay_or(self.cfg.monitor.delay_s)

    def linearize(self, progress: Callable[[dict[str, Any]], None] | None = None) -> CalibrationResult:
        with self._lock:
            lin = Linearization(self.cfg, self.optics, self.acquisition, self.safety, progress,
                                mzi_delay_s=self.monitor_delay_s())
            return lin.run(self._plain_drive(), self.cfg.laser)

    def check_linearization(self, calibration: CalibrationResult | None) -> HealthCheck | None:
        """The linearization health check of the drive a scan with ``calibration`` would use (the
        plain drive without one), against the monitor delay the scan uses (``monitor_delay_s``):
        :mod:`.calibration.health`. None when ``scan.linearity_check`` is off."""
        if not self.cfg.scan.linearity_check:
            return None
        with self._lock:
            drive = (drive_for_chirp(self.cfg, calibration.drive_v)
                     if (calibration is not None and calibration.drive_v.size) else self._plain_drive())
            return LinearizationHealth(self.cfg, self.optics, self.acquisition, self.safety,
                                       mzi_delay_s=self.monitor_delay_s()).check(drive)

    def selftest(self, progress: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
        with self._lock:
            return run_selftest(self.cfg, self.optics, self.acquisition, self.safety, self._plain_drive(),
                                progress)

    # -- simulation ------------------------------------------------------------------------------------
    def _hooks(self, what: str) -> SimHooks:
        if self._sim is None:
            raise NotSimulated(f"{what}: the instrument is real hardware; only a simulated bench has this")
        return self._sim

    def expect_scan(self, request: ScanRequest) -> bool:
        """A scan of ``request`` is coming (a one-shot command knows it before anything else has run):
        start what it will need now, beside the caller's set-up: the DSP's worker processes when its
        batches go to them (lidard.dsp_pool, ~1 s to start in processes of their own), and on a simulated
        bench its compiled synthesis kernels when this scan alone pays for loading them. Answers
        whether anything was started."""
        p = plan_scan(self.cfg, self.optics, request)
        pool = uses_dsp_processes(p, pool_workers())
        if pool:
            warm_in_background()
        hook = self._sim.expect_scan if self._sim is not None else None
        acq = p.acquisition
        kernels = hook is not None and bool(hook(acq.segments * acq.record_length * len(acq.channels)))
        return pool or kernels

    def set_scene(self, scene: dict[str, Any]) -> dict[str, Any]:
        """Simulation only: replace the bench's scene (the scene-file structure as a dict).

        Returns ``{"name", "targets"}``; a scene the bench refuses raises :class:`SceneRejected`
        naming what is wrong (the bench parses it: the daemon side does not know the scene format).
        """
        return self._hooks("set_scene").set_scene(scene)

    def inject_fault(self, kind: str, **params: Any) -> dict[str, Any]:
        """Simulation only: inject a bench fault (sim_devices.faults catalogue); returns it with its id."""
        hooks = self._hooks("inject_fault")
        try:
            return hooks.inject_fault(kind, **params)
        except SimFaultError:
            raise
        except (ValueError, TypeError) as exc:
            raise SimFaultError(f"fault {kind!r}: {exc}") from None

    def clear_faults(self, kind: str | None = None) -> int:
        hooks = self._hooks("clear_faults")
        try:
            return int(hooks.clear_faults(kind))
        except SimFaultError:
            raise
        except (ValueError, TypeError) as exc:
            raise SimFaultError(f"clear faults {kind!r}: {exc}") from None

    def active_faults(self) -> list[dict[str, Any]]:
        return list(self._hooks("active_faults").active_faults())

    def close(self) -> None:
        with self._lock:
            try:
                self.safety.bring_down()
            except Exception:
                pass
            self.registry.close()
            if self._on_close is not None:
                self._on_close()


def _ledger_difference(after: dict, before: dict) -> dict:
    """One scan's share of the bench's cumulative ledger: batches that modelled / skipped each effect."""
    out: dict[str, Any] = {}
    for key in ("modelled", "skipped"):
        a, b = after.get(key, {}), before.get(key, {})
        out[key] = {k: int(a[k]) - int(b.get(k, 0)) for k in a if int(a[k]) - int(b.get(k, 0)) > 0}
    out["rules"] = after.get("rules", {})
    return out
