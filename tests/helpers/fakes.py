"""A fake Instrument for daemon/API/CLI tests: synthetic points, honours cancel and progress.

Import it as ``from tests.helpers.fakes import FakeInstrument`` (pyproject sets pytest's pythonpath).
A scan can be held part-way (``hold_after`` pixels) until the test releases it or cancels it, so
cancel and queue-order tests need no sleeps.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from lidard.config import load_profile
from lidard.instrument.healthcheck import HealthCheck
from lidard.instrument.types import POINT_DTYPE, CalibrationResult, ScanProgress, ScanResult
from lidard.instrument.plan import plan

from lidard.instrument import NotSimulated  # what the simulation methods raise without a bench
from lidard.instrument.errors import FaultsStillOpen
from tests.helpers.deadlines import WAIT_S


class DeviceFault(Exception):
    pass

FRESH_CHIRP_ERROR_HZ = 50e3


class FakeInstrument:
    def __init__(self, profile: str = "fpsa128", simulated: bool = True, hold_after: int | None = None,
                 fail_with: Exception | None = None, hit=None):
        self.optics = load_profile(profile).optics()
        self.simulated = simulated
        self.hold_after = hold_after
        self.fail_with = fail_with
        self.hit = hit                       # hit(row, col) -> bool: which pixels see a target
        self.reached = threading.Event()     # set when a held scan reaches hold_after
        self.release = threading.Event()     # set by the test to let it continue
        self.requests = []
        self.calibrations_used = []
        self.linearize_calls = 0
        self.scenes = []
        self.closed = False
        self.temperature_c = 25.0            # the TEC readback laser_temperature_c() reports
        self.latched = []                    # controller faults latched (names), as controller_faults() reports
        self.interlock_closed = True
        # the chirp error check_linearization() measures (None: the check is off); a linearization
        # brings it down to FRESH_CHIRP_ERROR_HZ
        self.chirp_error_hz = None
        self.checks = 0

    def laser_temperature_c(self):
        return self.temperature_c

    def use_calibrations(self, applied):
        self.applied = applied

    def monitor_delay_s(self):
        delay = getattr(getattr(self, "applied", None), "delay_s", None)
        return 200e-9 if delay is None else delay

    def devices(self):
        return [{"name": n, "connected": True, "identity": f"fake-{n}", "state": "ready", "faults": []}
                for n in ("fpsa", "awg", "digitizer", "controller")]

    def controller_faults(self):
        return {"latched": sorted(self.latched), "interlock_closed": self.interlock_closed}

    def acknowledge_faults(self, by):
        # like the real one: refused while the interlock reads open, else the latches are cleared
        if not self.interlock_closed:
            raise FaultsStillOpen(["INTERLOCK_OPEN (the interlock loop reads open: close it first)"])
        cleared, self.latched = sorted(self.latched), []
        return {"cleared": cleared, "by": by, "at": time.time()}

    def scanner(self):
        return self.optics.summary()

    def check_linearization(self, calibration):
        if self.chirp_error_hz is None:
            return None
        self.checks += 1
        return HealthCheck(residual_hz=self.chirp_error_hz, up_error_hz=self.chirp_error_hz,
                           down_error_hz=self.chirp_error_hz, nonlinearity_hz=0.0,
                           relative=self.chirp_error_hz / 8.6e9, noise_floor_hz=0.0, threshold_hz=200e3,
                           records=16, hardware_time_s=16 * 160e-6, wall_time_s=0.0,
                           temperature_c=self.temperature_c)

    def linearize(self, progress=None):
        self.linearize_calls += 1
        if self.chirp_error_hz is not None:
            self.chirp_error_hz = FRESH_CHIRP_ERROR_HZ
        return CalibrationResult(
            iterations=[{"up_rms_hz": 4e6, "down_rms_hz": 5e6}, {"up_rms_hz": 4e4, "down_rms_hz": 1e5}],
            reduction={"up": 100.0, "down": 50.0}, converged=True, laser="dfb_default",
            temperature_c=self.temperature_c, drive_v=np.linspace(-1, 1, 64), fs_drive_hz=1e8)

    def run_scan(self, request, progress, cancel, calibration=None):
        self.requests.append(request)
        self.calibrations_used.append(calibration)
        if self.fail_with is not None:
            raise self.fail_with
        pixels = plan(request, self.optics)
        n = len(pixels)
        dirs = self.optics.directions(pixels[:, 0], pixels[:, 1])
        rng_m = 1.0 + 0.001 * pixels[:, 1]
        pts = np.zeros(n, dtype=POINT_DTYPE)
        xyz = dirs * rng_m[:, None]
        pts["x"], pts["y"], pts["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        pts["range"], pts["intensity"], pts["snr_db"] = rng_m, 0.1, 30.0
        pts["row"], pts["col"], pts["valid"] = pixels[:, 0], pixels[:, 1], 1
        pixel_s = 100e-6 * request.averages
        pts["t"] = np.arange(n) * pixel_s
        has_return = np.ones(n, dtype=bool) if self.hit is None else \
            np.array([bool(self.hit(int(r), int(c))) for r, c in pixels], dtype=bool)
        done = 0
        for i in range(n):
            if cancel.is_set():
                break
            done = i + 1
            if done % 16 == 0 or done == n:
                progress(ScanProgress(done, n, done, done * pixel_s))
            if self.hold_after is not None and done == self.hold_after:
                progress(ScanProgress(done, n, done, done * pixel_s))
                self.reached.set()
                while not (self.release.is_set() or cancel.is_set()):
                    self.release.wait(0.01)
        from lidard.instrument.types import ScanResult
        return ScanResult(points=pts[:done][has_return[:done]], meta={"fake": True, "chirp": {"ramp_s": 80e-6}},
                          pixels_scanned=done, pixels_planned=n, hardware_time_s=done * pixel_s,
                          partial=done < n)

    def run_stream(self, request, planner, on_frame, cancel, calibration=None, *, frames=None,
                   health_interval_s=60.0, on_points=None):
        """Frames of synthetic points (range 1 m + 1 mm per column + 1 cm per frame) on the planner's
        pixels, ``pixel_s`` apart, back to back; stops at ``frames`` or on ``cancel``."""
        from lidard.instrument.frames import Frame, StreamResult

        self.requests.append(request)
        self.calibrations_used.append(calibration)
        if self.fail_with is not None:
            raise self.fail_with
        pixel_s = 100e-6 * request.averages
        history, k, t0 = [], 0, 0.0
        while (frames is None or k < frames) and not cancel.is_set():
            fp = planner(k, list(history))
            px = np.asarray(fp.pixels, dtype=np.int64).reshape(-1, 2)
            pts = np.zeros(len(px), dtype=POINT_DTYPE)
            rng_m = 1.0 + 0.001 * px[:, 1] + 0.01 * k
            xyz = self.optics.directions(px[:, 0], px[:, 1]) * rng_m[:, None]
            pts["x"], pts["y"], pts["z"], pts["range"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], rng_m
            pts["row"], pts["col"], pts["valid"], pts["frame"] = px[:, 0], px[:, 1], 1, k
            pts["intensity"], pts["snr_db"] = 0.1, 30.0
            pts["t"] = t0 + np.arange(len(px)) * pixel_s
            frame = Frame(k, pts, px, len(px), t0, len(px) * pixel_s, 0.0, pixel_s, trade=dict(fp.trade))
            on_frame(frame)
            history = (history + [frame])[-4:]
            t0 += len(px) * pixel_s
            k += 1
        return StreamResult(k, t0, None, cancel.is_set(), [], {"fake": True})

    def expect_scan(self, request):
        return False            # nothing to prepare: the fake synthesizes nothing

    def set_scene(self, scene):
        # like the real instrument: the simulator's parser decides, a refusal is a ValueError
        from sim_devices.world.scene import Scene, SceneError

        if not self.simulated:
            raise NotImplementedError("real hardware")
        try:
            parsed = Scene.from_dict(scene, source="<request>")
        except SceneError as exc:
            raise ValueError(str(exc)) from None
        self.scenes.append(scene)
        return {"name": parsed.name, "targets": len(parsed)}

    def selftest(self, progress=None):
        # the fake has no switches to toggle: the worker reports this as a failed self-test (503)
        raise NotSimulated("the fake instrument has no FPSA to self-test")

    # Bench faults: the fake has no bench (the API answers 409, as for real hardware).
    def inject_fault(self, kind, **params):
        raise NotSimulated("the fake instrument has no bench to inject faults into")

    def clear_faults(self, kind=None):
        raise NotSimulated("the fake instrument has no bench to clear faults on")

    def active_faults(self):
        raise NotSimulated("the fake instrument has no bench faults")

    def close(self):
        self.closed = True


class StreamingInstrument(FakeInstrument):
    """Measures ``n`` points in two batches; holds after the first until the test releases it."""

    def __init__(self, n: int = 50, **kw):
        super().__init__(**kw)
        self.n = n
        self.first_batch = threading.Event()

    def run_scan(self, request, progress, cancel, calibration=None):
        pts = np.zeros(self.n, POINT_DTYPE)
        pts["range"] = np.linspace(0.5, 1.5, self.n)
        pts["z"], pts["row"], pts["col"] = pts["range"], np.arange(self.n) // 10, np.arange(self.n) % 10
        pts["velocity"], pts["t"], pts["valid"] = -0.25, np.arange(self.n) * 1e-4, 1
        half = self.n // 2
        progress(ScanProgress(half, self.n, half, 0.1, new_points=pts[:half]))
        self.first_batch.set()
        assert self.release.wait(WAIT_S)
        progress(ScanProgress(self.n, self.n, self.n, 0.2, new_points=pts[half:]))
        return ScanResult(points=pts, meta={}, pixels_scanned=self.n, pixels_planned=self.n, hardware_time_s=0.2)
