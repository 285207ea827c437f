"""The instrument: drivers + DSP composed into scans and calibrations (dissertation §4.4.1).

:class:`LidarInstrument` is the one object that owns the hardware (the job worker calls it from one
thread). A scan: check the interlock, bring HV and laser up (read back), load the (linearized) drive
waveform into the AWG, choose the ADC rate and record length from the requested maximum range and
the chirp, upload the pattern and timing to the FPGA, arm the digitizer, start, stream segments in
batches into the DSP (memory bounded: a batch of pixels at a time, never a whole frame of raw
samples), build points, stop, bring laser and HV down. The FPGA steps the pattern itself and
triggers the AWG and digitizer: there is no PC round trip per pixel.

:func:`open_instrument` is the composition root: it turns a configuration into running drivers, and
for a simulated configuration it first starts the simulated bench (embedded in this process or as a
child process) and takes the device addresses from it. This is the only place on the host side that
knows about the simulator.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from drivers.awg.driver import AwgDriver
from drivers.controller.driver import LaserHvController, SettleCheck
from drivers.controller.protocol import Limits
from drivers.digitizer.driver import DigitizerDriver
from drivers.fpsa.driver import FpsaController

from .config import Config
from .dsp.frame import FrameDsp
from .dsp.ilc import linearize as ilc_linearize
from .errors import LidardError
from .instrument_api import (POINT_DTYPE, CalibrationResult, ScanProgress, ScanRequest, ScanResult)
from .physics.chirp import adc_rate_hz, triangle_drive_v
from .scan import plan

AWG_RATE_HZ = 100e6          # drive samples: 16,000 per 160 us period
BATCH_BYTES = 8 << 20        # raw samples per DSP batch (bounded memory)


class InstrumentError(LidardError):
    """A scan or calibration could not run; the message names the device and the cause."""


@dataclass
class _AdcPlan:
    fs_hz: float
    ramp_samples: int
    record_length: int
    bits: int


class LidarInstrument:
    def __init__(self, cfg: Config, *, fpsa: FpsaController, awg: AwgDriver, digitizer: DigitizerDriver,
                 controller: LaserHvController, simulated: bool, sleep: Callable[[float], object] = time.sleep,
                 set_scene: Callable[[dict], None] | None = None, on_close: Callable[[], None] | None = None):
        self.cfg = cfg
        self.profile = cfg.load_profile()
        self.laser = cfg.load_laser()
        self.optics = self.profile.optics(cfg.lens, cfg.chirp.wavelength_m)
        self.fpsa, self.awg, self.digitizer, self.controller = fpsa, awg, digitizer, controller
        self.simulated = simulated
        self._sleep = sleep
        self._set_scene = set_scene
        self._on_close = on_close
        self._lock = threading.RLock()
        self._identity: dict[str, Any] = {}
        self._identify_all()
        # The HV583 registers power up with random contents (ghost beams): clear them first.
        try:
            self.fpsa.reset()
        except Exception as exc:
            self._identity["fpsa"] = f"reset failed: {exc}"

    # -- information ----------------------------------------------------------------------------------
    def _identify_all(self) -> None:
        for name, fn in (("fpsa", self.fpsa.identify), ("awg", self.awg.identify),
                         ("digitizer", self.digitizer.identify), ("controller", self.controller.identify)):
            try:
                ident = fn()
                self._identity[name] = ident if isinstance(ident, str) else repr(ident)
            except Exception as exc:  # reported by devices(); a scan will fail with the cause
                self._identity[name] = f"unreachable: {exc}"

    def devices(self) -> list[dict[str, Any]]:
        out = []
        checks = (("fpsa", lambda: self.fpsa.status()), ("awg", lambda: self.awg.errors()),
                  ("digitizer", lambda: self.digitizer.status()), ("controller", lambda: self.controller.status()))
        with self._lock:
            for name, fn in checks:
                try:
                    state = fn()
                    out.append({"name": name, "connected": True, "identity": self._identity.get(name),
                                "state": repr(state), "faults": _faults_of(state)})
                except Exception as exc:
                    out.append({"name": name, "connected": False, "identity": self._identity.get(name),
                                "state": "unreachable", "faults": [f"{type(exc).__name__}: {exc}"]})
        return out

    def scanner(self) -> dict[str, Any]:
        return self.optics.summary()

    # -- pieces of a scan -------------------------------------------------------------------------------
    def _settle(self) -> SettleCheck:
        return SettleCheck(sleep=self._sleep, timeout_s=30.0, poll_s=0.002)

    def _bring_up(self) -> None:
        if not self.controller.interlock_closed():
            raise InstrumentError("controller: interlock open; close it before scanning")
        self.controller.bring_up(self.cfg.devices.controller.laser_current_ma, self.profile.actuation_v,
                                 settle_check=self._settle())

    def _bring_down(self) -> None:
        try:
            self.controller.bring_down(settle_check=self._settle())
        except Exception:
            # Safety first: at least command the outputs off even when the readback fails.
            for fn in (lambda: self.controller.laser_enable(False), lambda: self.controller.hv_enable(False)):
                try:
                    fn()
                except Exception:
                    pass
            raise

    def _plain_drive(self) -> np.ndarray:
        c = self.cfg.chirp
        return triangle_drive_v(c.excursion_hz, c.ramp_s, AWG_RATE_HZ, self.laser.static_tuning_hz_per_v)

    def _load_drive(self, drive_v: np.ndarray) -> None:
        self.awg.output(False)
        self.awg.set_sample_rate(AWG_RATE_HZ)
        self.awg.upload_waveform(drive_v, units="volts")
        self.awg.set_trigger_external(True)
        self.awg.output(True)

    def _adc_plan(self, max_range_m: float, *, max_range_for_mzi: bool = False) -> _AdcPlan:
        c, a = self.cfg.chirp, self.cfg.adc
        doppler = 2 * self.cfg.scan.max_speed_mps / c.wavelength_m
        fs = adc_rate_hz(max_range_m, c.rate_hz_per_s, max_doppler_hz=doppler, oversample=a.oversample,
                         max_rate_hz=a.max_sample_rate_hz, min_rate_hz=a.min_sample_rate_hz, ramp_s=c.ramp_s)
        r = int(round(fs * c.ramp_s))
        # 16-bit records: the digitizer decimates its full-rate core on board (more bits at low rates)
        return _AdcPlan(fs_hz=fs, ramp_samples=r, record_length=2 * r, bits=16)

    def _run_pattern(self, pixels: np.ndarray, triggers_per_pixel: int) -> None:
        period_ns = int(round(2 * self.cfg.chirp.ramp_s * 1e9))
        self.fpsa.upload_pattern(pixels)
        self.fpsa.set_timing(settle_ns=int(self.cfg.scan.settle_s * 1e9), dwell_ns=0,
                             triggers_per_pixel=int(triggers_per_pixel), trigger_period_ns=period_ns)

    # -- scan -------------------------------------------------------------------------------------------
    def run_scan(self, request: ScanRequest, progress, cancel: threading.Event,
                 calibration: CalibrationResult | None = None) -> ScanResult:
        with self._lock:
            return self._run_scan(request, progress, cancel, calibration)

    def _run_scan(self, request, progress, cancel, calibration) -> ScanResult:
        pixels = plan(request, self.optics)
        n_pix = len(pixels)
        avg = int(request.averages)
        adc = self._adc_plan(request.max_range_m)
        dsp = FrameDsp(ramp_samples=adc.ramp_samples, fs_hz=adc.fs_hz,
                       chirp_rate_hz_per_s=self.cfg.chirp.rate_hz_per_s, wavelength_m=self.cfg.chirp.wavelength_m,
                       max_range_m=request.max_range_m, max_speed_mps=self.cfg.scan.max_speed_mps,
                       window=self.cfg.scan.window, pfa=self.cfg.scan.pfa, max_returns=self.cfg.scan.max_returns)
        progress(ScanProgress(0, n_pix, 0, 0.0, stage="preparing"))
        chunks: list[np.ndarray] = []
        done = 0
        hw_t0 = None
        hw_last = 0.0
        partial = False
        self._bring_up()
        try:
            drive = calibration.drive_v if (calibration is not None and calibration.drive_v.size) else self._plain_drive()
            self._load_drive(drive)
            self._run_pattern(pixels, avg)
            cfgd = self.digitizer.configure(channels=("beat",), sample_rate_hz=adc.fs_hz,
                                            record_length=adc.record_length, segments=n_pix * avg,
                                            bits=adc.bits, input_range_v=self.cfg.adc.input_range_v)
            lsb = self.cfg.adc.input_range_v / 2 ** adc.bits
            self.digitizer.arm()
            self.fpsa.arm()
            self.fpsa.start()
            bytes_per_pix = avg * adc.record_length * (1 if adc.bits == 8 else 2)
            batch_pix = max(1, min(n_pix, BATCH_BYTES // max(1, bytes_per_pix)))
            while done < n_pix:
                if cancel.is_set():
                    partial = True
                    break
                bp = min(batch_pix, n_pix - done)
                headers, samples = self.digitizer.read_segments(done * avg, bp * avg, cfgd)
                t_ns = np.array([h.trigger_time_ns for h in headers], dtype=np.float64)
                if hw_t0 is None:
                    hw_t0 = t_ns[0]
                beat = samples[:, 0, :].reshape(bp, avg, adc.record_length)
                res = dsp.process(beat, lsb)
                px = pixels[done:done + bp]
                t_pix = (t_ns.reshape(bp, avg)[:, 0] - hw_t0) * 1e-9
                chunks.append(self._points(res, px, t_pix))
                done += bp
                hw_last = (t_ns[-1] - hw_t0) * 1e-9 + adc.record_length / adc.fs_hz
                progress(ScanProgress(done, n_pix, int(sum(len(c) for c in chunks)), hw_last))
        finally:
            try:
                self.fpsa.stop()
            finally:
                self._bring_down()
        points = np.concatenate(chunks) if chunks else np.zeros(0, POINT_DTYPE)
        meta = {
            "adc": {"sample_rate_hz": adc.fs_hz, "record_length": adc.record_length, "bits": adc.bits,
                    "ramp_samples": adc.ramp_samples, "input_range_v": self.cfg.adc.input_range_v},
            "dsp": {"window": dsp.window, "estimator": dsp.estimator, "pfa": dsp.pfa,
                    "range_resolution_m": dsp.range_resolution_m, "use_fraction": dsp.use_fraction},
            "simulated": self.simulated,
            "calibration_id": (calibration.meta or {}).get("id") if calibration else None,
        }
        return ScanResult(points=points, meta=meta, pixels_scanned=done, pixels_planned=n_pix,
                          hardware_time_s=hw_last, partial=partial)

    def _points(self, res, px: np.ndarray, t_pix: np.ndarray) -> np.ndarray:
        pi, ki = np.nonzero(res.present)
        out = np.zeros(len(pi), POINT_DTYPE)
        if not len(pi):
            return out
        rows, cols = px[pi, 0], px[pi, 1]
        rng_m = res.range_m[pi, ki]
        d = self.optics.directions(rows, cols)
        xyz = d * rng_m[:, None]
        out["x"], out["y"], out["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        out["range"] = rng_m
        out["velocity"] = res.velocity_mps[pi, ki]
        out["intensity"] = res.intensity_v[pi, ki]
        out["snr_db"] = res.snr_db[pi, ki]
        out["row"], out["col"] = rows, cols
        # return_index: order along the beam by range
        order = np.lexsort((rng_m, pi))
        ri = np.zeros(len(pi), np.int64)
        same = np.r_[False, pi[order][1:] == pi[order][:-1]]
        run = np.cumsum(~same) - 1
        starts = np.flatnonzero(~same)
        ri[order] = np.arange(len(pi)) - starts[run]
        out["return_index"] = ri
        out["t"] = t_pix[pi]
        out["valid"] = res.valid[pi, ki]
        return out

    # -- calibration ------------------------------------------------------------------------------------
    def linearize(self, progress=None) -> CalibrationResult:
        with self._lock:
            return self._linearize(progress)

    def _linearize(self, progress) -> CalibrationResult:
        c = self.cfg.chirp
        tau_m = self.cfg.monitor.delay_s
        # The MZI beat (gamma tau_m) sets the rate, not the scan range.
        f_mzi = c.rate_hz_per_s * tau_m
        fs = adc_rate_hz(1.0, c.rate_hz_per_s, max_doppler_hz=f_mzi * 2.0, oversample=4.0,
                         max_rate_hz=self.cfg.adc.max_sample_rate_hz, min_rate_hz=self.cfg.adc.min_sample_rate_hz,
                         ramp_s=c.ramp_s)
        r = int(round(fs * c.ramp_s))
        bits = 16
        centre = np.array([[self.optics.bonded_rows[len(self.optics.bonded_rows) // 2], self.optics.cols // 2]])
        self._bring_up()
        history: list[dict[str, float]] = []
        try:
            def measure(drive_v: np.ndarray, n_avg: int) -> np.ndarray:
                self._load_drive(drive_v)
                self._run_pattern(centre, n_avg)
                cfgd = self.digitizer.configure(channels=("mzi",), sample_rate_hz=fs, record_length=2 * r,
                                                segments=n_avg, bits=bits, input_range_v=self.cfg.adc.input_range_v)
                self.digitizer.arm()
                self.fpsa.arm()
                self.fpsa.start()
                _, samples = self.digitizer.read_segments(0, n_avg, cfgd)
                self.fpsa.stop()
                history.append({})
                if progress is not None:
                    progress({"measurements": len(history)})
                return samples[:, 0, :].astype(np.float64)

            res = ilc_linearize(measure, self._plain_drive(), fs_drive_hz=AWG_RATE_HZ, fs_adc_hz=fs,
                                ramp_s=c.ramp_s, excursion_hz=c.excursion_hz, mzi_delay_s=tau_m, averages=32)
        finally:
            self._bring_down()
        iters = [{"up_rms_hz": float(it["up_rms_hz"]), "down_rms_hz": float(it["down_rms_hz"])}
                 for it in res.iterations]
        try:
            temp = float(self.controller.tec_c())
        except Exception:
            temp = float("nan")
        return CalibrationResult(iterations=iters, reduction={k: float(v) for k, v in dict(res.reduction).items()},
                                 converged=bool(res.converged), laser=self.cfg.laser, temperature_c=temp,
                                 drive_v=np.asarray(res.drive_v, dtype=np.float64), fs_drive_hz=AWG_RATE_HZ,
                                 meta={"mzi_delay_s": tau_m, "adc_rate_hz": fs})

    # -- simulation ------------------------------------------------------------------------------------
    def set_scene(self, scene: dict[str, Any]) -> None:
        if self._set_scene is None:
            raise NotImplementedError("set_scene: only a simulated bench has a scene")
        self._set_scene(scene)

    def close(self) -> None:
        with self._lock:
            try:
                self._bring_down()
            except Exception:
                pass
            for dev in (self.fpsa, self.controller):
                try:
                    dev.close()
                except Exception:
                    pass
            if self._on_close is not None:
                self._on_close()


def _faults_of(state: Any) -> list[str]:
    faults = getattr(state, "faults", None)
    if faults is None:
        return []
    if isinstance(faults, (set, frozenset, list, tuple)):
        return sorted(str(f) for f in faults)
    try:
        return [str(f) for f in type(faults) if f in faults and int(f)]
    except TypeError:
        return [str(faults)] if faults else []


# --------------------------------------------------------------------------------------------------
# Composition root
# --------------------------------------------------------------------------------------------------
def _usb_device(backend, spec: str, default_ids: tuple[int, int], who: str):
    import usb.core

    if spec == "bench":
        vid, pid = default_ids
    else:
        try:
            vid_s, pid_s = spec.split(":")
            vid, pid = int(vid_s, 16), int(pid_s, 16)
        except ValueError:
            raise InstrumentError(f"{who}: usb address {spec!r} is not VID:PID (hex)") from None
    dev = usb.core.find(idVendor=vid, idProduct=pid, backend=backend)
    if dev is None:
        raise InstrumentError(f"{who}: no USB device {vid:04x}:{pid:04x} found")
    return dev


def _connect(cfg: Config, endpoints: dict[str, Any] | None, usb_backend, sleep) -> dict[str, Any]:
    from drivers.awg import protocol as awg_p
    from drivers.digitizer import protocol as dig_p

    d = cfg.devices
    fpsa_url = endpoints["fpsa_url"] if endpoints and d.fpsa.url == "bench" else d.fpsa.url
    host = endpoints["controller_host"] if endpoints and d.controller.host == "bench" else d.controller.host
    port = endpoints["controller_port"] if endpoints and d.controller.host == "bench" else d.controller.port
    fpsa = FpsaController(fpsa_url, timeout_s=d.fpsa.timeout_s, baudrate=d.fpsa.baudrate)
    ctrl = LaserHvController(host, port, device_id=d.controller.device_id, timeout_s=d.controller.timeout_s,
                             limits=Limits(max_laser_current_ma=d.controller.max_laser_current_ma,
                                           max_hv_v=d.controller.max_hv_v, tec_range_c=(15.0, 40.0)))
    awg = AwgDriver(_usb_device(usb_backend, d.awg.usb, (awg_p.AWG_VID, awg_p.AWG_PID), "awg"))
    dig = DigitizerDriver(_usb_device(usb_backend, d.digitizer.usb,
                                      (dig_p.DIGITIZER_VID, dig_p.DIGITIZER_PID), "digitizer"))
    return {"fpsa": fpsa, "controller": ctrl, "awg": awg, "digitizer": dig}


def open_instrument(cfg: Config, *, scene_path: str | None = None, bench: str | None = None) -> LidarInstrument:
    """Build the instrument a configuration describes.

    Simulated configurations start the bench first: ``bench="embedded"`` runs it in this process
    (the default of ``lidarctl scan --sim``), ``"child"`` as a ``lidar-sim`` child process that talks
    over a real pty, Modbus TCP and the USB socket bridge (the daemon's default, ``sim.bench``).
    """
    if not cfg.sim.enabled:
        if scene_path is not None:
            raise InstrumentError("--scene needs a simulated configuration (sim.enabled = true)")
        from usb.backend import libusb1

        parts = _connect(cfg, None, libusb1.get_backend(), time.sleep)
        return LidarInstrument(cfg, simulated=False, **parts)
    mode = bench or cfg.sim.bench
    if mode == "embedded":
        from sim_devices.bench import Bench
        from sim_devices.world.scene import Scene

        scene = Scene.from_toml(scene_path) if scene_path else None
        b = Bench(cfg, scene)
        ep = b.start(usb="inproc")
        parts = _connect(cfg, ep, b.usb_backend, b.clock.advance)
        from sim_devices.world.scene import Scene as _Scene

        return LidarInstrument(cfg, simulated=True, sleep=b.clock.advance,
                               set_scene=lambda d: b.set_scene(_Scene.from_dict(d, source="<request>")),
                               on_close=b.close, **parts)
    if mode != "child":
        raise InstrumentError(f"sim.bench must be 'embedded' or 'child', got {mode!r}")
    from sim_devices.bench import BenchControlClient
    from sim_devices.usb_backend import backend_from_url

    cmd = [sys.executable, "-m", "sim_devices.bench", "--json", "--config", cfg.source.split(" (+env")[0]]
    if cfg.source.startswith("<"):
        cmd = cmd[:-2]
    if scene_path:
        cmd += ["--scene", str(scene_path)]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=os.environ.copy())
    line = proc.stdout.readline()
    if not line:
        proc.kill()
        raise InstrumentError("simulated bench: the lidar-sim child process did not start")
    ep = json.loads(line)
    ctl = BenchControlClient(ep["control_port"])

    def advance(dt_s: float) -> None:
        ctl.call("advance", dt_s=float(dt_s))

    def stop_child() -> None:
        ctl.close()
        try:
            proc.stdin.close()
            proc.wait(timeout=10)
        except Exception:
            proc.kill()

    parts = _connect(cfg, ep, backend_from_url(ep["usb_url"]), advance)
    return LidarInstrument(cfg, simulated=True, sleep=advance,
                           set_scene=lambda d: ctl.call("set_scene", scene=d), on_close=stop_child, **parts)
