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

Faults (issue 6; docs/reliability.md):

* Transient faults are retried where they happen: each driver retries its own transfers (FPSA
  resend, USB retry and re-find, Modbus reconnect); on top of that a whole batch of segments whose
  read fails (timeout, disconnect, bad CRC) is re-read up to ``BATCH_RETRIES`` times with
  exponential backoff (segments are addressed by index, so a re-read is idempotent), each retry
  logged and counted in the scan meta (``faults.batch_retries``). When the acquisition itself is
  lost (a replugged digitizer forgets it), the rest of the pattern is started as a new acquisition
  from the first pixel not yet read (``faults.resumes``, at most ``RESUMES``). A device that stays down fails
  the scan with :class:`ScanFailed` naming the device and the cause; the points measured so far
  ride on the exception and are written by the worker (nothing measured is lost).
* Safety between batches: reads are limited to ``SAFETY_CHECK_S`` of hardware time (the DSP still
  runs on batches of up to ``BATCH_BYTES``, collected from several reads), and after each read one
  Modbus request reads the controller's flags (interlock, outputs, fault summary).
  Interlock open or a latched fault (HV fault) -> laser off and HV off are COMMANDED FIRST, then
  read back to 0 (:meth:`LidarInstrument._safe_state`), and only then the FPGA is stopped; the batch
  in flight when it happened is discarded (its light is unknown), the points before it are kept and
  the result is ``partial`` with ``stop_reason`` naming the cause and the readbacks.
* Digitizer overrange: points from pixels with a clipped segment get ``valid = 0`` and the meta
  counts the clipped segments and pixels (never reported as good points).
* :meth:`LidarInstrument.selftest` toggles every bonded row and every column through the monitor
  "tap" channel and reports stuck-on / stuck-off switches.
"""

from __future__ import annotations

import collections
import json
import logging
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
from drivers.usbtmc import DeviceDisconnected, DeviceStall, DeviceTimeout as UsbTimeout, UsbDeviceError

from .config import Config
from .dsp.frame import FrameDsp
from .dsp.ilc import linearize as ilc_linearize
from .dsp.pnframe import compensator_for, gate_m_range
from .dsp.rangefft import C_M_PER_S
from .errors import LidardError
from .instrument_api import (POINT_DTYPE, CalibrationResult, ScanProgress, ScanRequest, ScanResult)
from .physics.chirp import adc_rate_hz, triangle_drive_v
from .raw.points import frame_points
from .scan import plan

AWG_RATE_HZ = 100e6          # drive samples: 16,000 per 160 us period
# The AWG's output stage: |offset| + amplitude <= devices.awg.max_output_v (default 5 V,
# docs/protocols/awg.md), i.e. |drive| <= that. No drive beyond it is ever uploaded: the ILC is capped at
# it and _load_drive refuses first.
BATCH_BYTES = 8 << 20
DEVICE_NAMES = ("fpsa", "awg", "digitizer", "controller")
DEVICES_WAIT_S = 0.5         # GET /devices waits this long for the instrument before answering "busy"        # raw samples per DSP batch (bounded memory)
# Hardware time per read: the interlock/fault flags are read between reads, so this bounds the
# host's reaction time (the controller's own hardware interlock drops the outputs at once anyway).
# Each read has a fixed cost (in the simulator mostly the FPGA model's per-call beam bookkeeping):
# 50 ms reads cost ~15-20 % of the simulated bench's throughput against unbounded reads, 10 ms ~50 %
# (benchmarks/reliability.py --tradeoff, docs/reliability.md).
SAFETY_CHECK_S = 0.05
BATCH_RETRIES = 3            # re-reads of a failed batch of segments
BATCH_BACKOFF_S = 0.005      # first backoff between batch re-reads (doubles)
RESUMES = 2                  # new acquisitions for the rest of a scan after one was lost

log = logging.getLogger(__name__)


class InstrumentError(LidardError):
    """A scan or calibration could not run; the message names the device and the cause."""


class ScanFailed(InstrumentError):
    """A device stayed down mid-scan. ``partial`` holds the points measured before (may be None)."""

    def __init__(self, message: str, partial: ScanResult | None = None):
        super().__init__(message)
        self.partial = partial


class NotSimulated(InstrumentError):
    """A simulation-only operation (scene, fault injection) was asked of real hardware."""


class SimFaultError(InstrumentError, ValueError):
    """The simulated bench refused a fault (unknown kind or bad parameter); names it."""


class SceneRejected(InstrumentError, ValueError):
    """The simulated bench refused a scene; the message names the key or target that is wrong."""


@dataclass
class SimHooks:
    """What the composition root gives the instrument to reach a simulated bench."""

    set_scene: Callable[[dict], dict]
    inject_fault: Callable[..., dict]
    clear_faults: Callable[[str | None], int]
    active_faults: Callable[[], list]


@dataclass
class _AdcPlan:
    fs_hz: float
    ramp_samples: int
    record_length: int
    bits: int


class LidarInstrument:
    def __init__(self, cfg: Config, *, fpsa: FpsaController, awg: AwgDriver, digitizer: DigitizerDriver,
                 controller: LaserHvController, simulated: bool, sleep: Callable[[float], object] = time.sleep,
                 set_scene: Callable[[dict], None] | None = None, on_close: Callable[[], None] | None = None,
                 now: Callable[[], float] = time.monotonic, sim: SimHooks | None = None):
        self.cfg = cfg
        self.profile = cfg.load_profile()
        self.laser = cfg.load_laser()
        self.optics = self.profile.optics(cfg.lens, cfg.chirp.wavelength_m)
        self.fpsa, self.awg, self.digitizer, self.controller = fpsa, awg, digitizer, controller
        self.simulated = simulated
        self._sleep = sleep
        self._now = now
        self._sim = sim
        self._set_scene = set_scene if set_scene is not None else (sim.set_scene if sim else None)
        self._on_close = on_close
        self._lock = threading.RLock()
        self._identity: dict[str, Any] = {}
        self._last_devices: list[dict[str, Any]] = []
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
            return [{**e, "state": "busy: in use by the running job (last check shown)", "reconnected": False}
                    for e in self._last_devices] or [
                {"name": n, "connected": not str(self._identity.get(n, "")).startswith("unreachable"),
                 "reconnected": False, "identity": self._identity.get(n),
                 "state": "busy: in use by the running job", "faults": []} for n in DEVICE_NAMES]
        try:
            self._last_devices = self._check_devices()
            return self._last_devices
        finally:
            self._lock.release()

    def _check_devices(self) -> list[dict[str, Any]]:
        out = []
        checks = (("fpsa", self.fpsa, lambda: self.fpsa.status()), ("awg", self.awg, lambda: self.awg.errors()),
                  ("digitizer", self.digitizer, lambda: self.digitizer.status()),
                  ("controller", self.controller, lambda: self.controller.status()))
        for name, dev, fn in checks:
            entry: dict[str, Any] = {"name": name, "reconnected": False}
            n_before = getattr(dev, "reconnect_count", 0)
            try:
                state = fn()
                # the driver may have reopened its link by itself while answering
                entry["reconnected"] = getattr(dev, "reconnect_count", 0) != n_before
            except Exception as exc:
                first = f"{type(exc).__name__}: {exc}"
                try:
                    dev.reconnect()
                    state = fn()
                    entry["reconnected"] = True
                    log.warning("%s: reconnected (was: %s)", name, first)
                    if name not in self._identity or str(self._identity[name]).startswith("unreachable"):
                        self._identify_one(name)
                except Exception as exc2:
                    entry.update(connected=False, identity=self._identity.get(name), state="unreachable",
                                 faults=[first] + ([f"reconnect: {type(exc2).__name__}: {exc2}"]
                                                   if str(exc2) != str(exc) else []))
                    out.append(entry)
                    continue
            entry.update(connected=True, identity=self._identity.get(name), state=repr(state),
                         faults=_faults_of(state))
            out.append(entry)
        return out

    def _identify_one(self, name: str) -> None:
        fn = {"fpsa": self.fpsa.identify, "awg": self.awg.identify, "digitizer": self.digitizer.identify,
              "controller": self.controller.identify}[name]
        try:
            ident = fn()
            self._identity[name] = ident if isinstance(ident, str) else repr(ident)
        except Exception as exc:
            self._identity[name] = f"unreachable: {exc}"

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
        d = np.asarray(drive_v, dtype=np.float64)
        peak = float(np.max(np.abs(d))) if d.size else 0.0
        limit = self.cfg.devices.awg.max_output_v
        if not (d.ndim == 1 and d.size >= 2 and np.all(np.isfinite(d)) and peak <= limit):
            raise InstrumentError(f"awg: refusing drive waveform (shape {d.shape}, peak {peak:.4g} V): it must be "
                                  f"finite and within the output range of +-{limit:g} V "
                                  "(devices.awg.max_output_v); nothing uploaded")
        self.awg.output(False)
        self.awg.set_sample_rate(AWG_RATE_HZ)
        self.awg.upload_waveform(d, units="volts")
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
    def _phase_noise_on(self, request: ScanRequest) -> bool:
        """Resolve scan.phase_noise_compensation (or the request's override): "auto" is on when the
        round trip of max_range_m is at least twice the monitor delay (config.ScanDefaults)."""
        mode = getattr(request, "phase_noise_compensation", None) or self.cfg.scan.phase_noise_compensation
        if mode not in ("auto", "on", "off"):
            raise InstrumentError(f"scan: phase_noise_compensation={mode!r} is not one of 'auto', 'on', 'off'")
        if mode == "auto":
            return 2 * float(request.max_range_m) / C_M_PER_S >= 2 * self.cfg.monitor.delay_s
        return mode == "on"

    def run_scan(self, request: ScanRequest, progress, cancel: threading.Event,
                 calibration: CalibrationResult | None = None, raw_path=None) -> ScanResult:
        """``raw_path``: record the digitizer's raw segments there (lidard.raw; ``record_raw``)."""
        with self._lock:
            return self._run_scan(request, progress, cancel, calibration, raw_path)

    def _recorder(self, raw_path, pixels, avg, cfgd, adc, dsp, lsb, pn_on, tau_m, calibration, request, drive):
        from .raw.record import ScanRecorder
        return ScanRecorder.start(
            raw_path, pixels=pixels, directions=self.optics.directions(pixels[:, 0], pixels[:, 1]), averages=avg,
            channels=tuple(cfgd.channels), record_length=adc.record_length, dsp=dsp, lsb_v=lsb, phase_noise=pn_on,
            mzi_delay_s=tau_m, adc={"sample_rate_hz": adc.fs_hz, "record_length": adc.record_length, "bits": adc.bits,
                                    "ramp_samples": adc.ramp_samples, "input_range_v": self.cfg.adc.input_range_v},
            chirp=self.cfg.chirp.model_dump(), calibration_id=(calibration.meta or {}).get("id") if calibration else None,
            scan={"max_range_m": float(request.max_range_m), "averages": avg, "pattern": request.pattern},
            drive_v=drive)

    def _run_scan(self, request, progress, cancel, calibration, raw_path=None) -> ScanResult:
        pixels = plan(request, self.optics)
        n_pix = len(pixels)
        avg = int(request.averages)
        tau_m = self.cfg.monitor.delay_s
        pn_on = self._phase_noise_on(request)
        # the MZI beat (gamma tau_m) and its demodulation band (to 1.5 gamma tau_m) must be sampled too
        adc = self._adc_plan(max(request.max_range_m, 1.5 * C_M_PER_S * tau_m / 2) if pn_on
                             else request.max_range_m)
        channels = ("beat", "mzi") if pn_on else ("beat",)
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
        stop_reason: str | None = None
        faults: dict[str, Any] = {"batch_retries": 0, "resumes": 0, "overrange_segments": 0,
                                  "overrange_pixels": 0}
        base = 0            # first pixel of the current acquisition (> 0 after a resume)
        t_shift_s = 0.0
        safe: dict[str, Any] | None = None
        lsb = self.cfg.adc.input_range_v / 2 ** adc.bits
        # Raw batches wait here until BATCH_BYTES are together: the safety check wants short reads,
        # the DSP wants long batches (its per-call set-up costs as much as many pixels).
        pending: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]] = []
        pending_bytes = [0]

        def flush() -> None:
            if not pending:
                return
            beat = np.concatenate([p[0] for p in pending])
            px = np.concatenate([p[1] for p in pending])
            t_pix = np.concatenate([p[2] for p in pending])
            clipped = np.concatenate([p[3] for p in pending])
            mzi = np.concatenate([p[4] for p in pending]) if pn_on else None
            pending.clear()
            pending_bytes[0] = 0
            res = dsp.process(beat, lsb, mzi=mzi, mzi_delay_s=tau_m, mzi_lsb_v=lsb)
            chunks.append(frame_points(res, px, t_pix, self.optics.directions(px[:, 0], px[:, 1]), clipped))

        def result() -> ScanResult:
            try:
                flush()
            except Exception as exc:  # report what can be reported; the cause is already failing
                log.warning("processing the last batch failed: %s", exc)
            points = np.concatenate(chunks) if chunks else np.zeros(0, POINT_DTYPE)
            meta = {
                "adc": {"sample_rate_hz": adc.fs_hz, "record_length": adc.record_length, "bits": adc.bits,
                        "ramp_samples": adc.ramp_samples, "input_range_v": self.cfg.adc.input_range_v},
                "dsp": {"window": dsp.window, "estimator": dsp.estimator, "pfa": dsp.pfa,
                        "range_resolution_m": dsp.range_resolution_m, "use_fraction": dsp.use_fraction,
                        "phase_noise_compensation": pn_on},
                "simulated": self.simulated,
                "calibration_id": (calibration.meta or {}).get("id") if calibration else None,
                "faults": dict(faults),
            }
            if pn_on:
                comp = compensator_for(dsp, tau_m)
                meta["dsp"]["phase_noise"] = {
                    "mzi_delay_s": tau_m, "mzi_beat_hz": comp.mzi_beat_hz, "m_max": comp.m_max,
                    # nearest M of the bins inside the range gate (0 = uncompensated near ranges)
                    "m_range": list(gate_m_range(dsp, tau_m))}
            if recorder[0] is not None:
                recorder[0].close(pixels_scanned=done, stop_reason=stop_reason)
                meta["raw"] = {"pixels": done, "error": recorder[0].error}
            if safe is not None:
                meta["safe_state"] = safe
            if stop_reason is not None:
                meta["stop_reason"] = stop_reason
            return ScanResult(points=points, meta=meta, pixels_scanned=done, pixels_planned=n_pix,
                              hardware_time_s=hw_last, partial=partial or stop_reason is not None,
                              stop_reason=stop_reason)

        recorder = [None]
        self._bring_up()
        stopped_safe = False
        try:
            drive = calibration.drive_v if (calibration is not None and calibration.drive_v.size) else self._plain_drive()
            self._load_drive(drive)
            self._run_pattern(pixels, avg)
            self.digitizer.abort()   # an acquisition a failed job left armed would lock the settings
            cfgd = self.digitizer.configure(channels=channels, sample_rate_hz=adc.fs_hz,
                                            record_length=adc.record_length, segments=n_pix * avg,
                                            bits=adc.bits, input_range_v=self.cfg.adc.input_range_v)
            if raw_path is not None:
                recorder[0] = self._recorder(raw_path, pixels, avg, cfgd, adc, dsp, lsb, pn_on, tau_m, calibration,
                                             request, drive)
            self.digitizer.arm()
            self.fpsa.arm()
            self.fpsa.start()
            bytes_per_pix = avg * adc.record_length * (1 if adc.bits == 8 else 2) * len(channels)
            pixel_s = avg * 2 * self.cfg.chirp.ramp_s + self.cfg.scan.settle_s
            batch_pix = max(1, min(n_pix, BATCH_BYTES // max(1, bytes_per_pix), int(SAFETY_CHECK_S / pixel_s)))
            while done < n_pix:
                if cancel.is_set():
                    partial = True
                    break
                bp = min(batch_pix, n_pix - done)
                try:
                    headers, samples = self._read_batch((done - base) * avg, bp * avg, cfgd, faults)
                except InstrumentError as exc:
                    # before blaming the digitizer: did the interlock or a fault stop the light?
                    reason = self._safety_trip()
                    if reason is not None:
                        safe = self._safe_state()
                        stopped_safe = True
                        stop_reason = f"{reason}; {_describe_safe(safe)}"
                        break
                    if faults["resumes"] >= RESUMES:
                        raise ScanFailed(str(exc), result()) from exc
                    # The acquisition itself is lost (a replugged digitizer resets it): run the rest
                    # of the pattern as a new acquisition from the first pixel not yet read.
                    faults["resumes"] += 1
                    log.warning("scan: resuming from pixel %d of %d after %s", done, n_pix, exc)
                    try:
                        cfgd = self._resume(pixels[done:], avg, adc, channels)
                    except Exception as exc2:
                        raise ScanFailed(f"{_device_of(exc2)}: resume after '{exc}' failed: "
                                         f"{type(exc2).__name__}: {exc2}", result()) from exc2
                    base = done
                    t_shift_s = hw_last
                    hw_t0 = None
                    continue
                reason = self._safety_trip()
                if reason is not None:
                    # Outputs first; the batch in flight is discarded (when the light went is unknown).
                    safe = self._safe_state()
                    stopped_safe = True
                    stop_reason = f"{reason}; {_describe_safe(safe)}"
                    faults["discarded_pixels"] = bp
                    log.warning("scan stopped after %d of %d pixels: %s", done, n_pix, stop_reason)
                    break
                t_ns = np.array([h.trigger_time_ns for h in headers], dtype=np.float64)
                if hw_t0 is None:
                    # after a resume the new run's clock continues where the last pixel read ended
                    hw_t0 = t_ns[0] - t_shift_s * 1e9
                # the record lists channels in the digitizer's order (channel bits), not ours
                beat = samples[:, cfgd.channels.index("beat"), :].reshape(bp, avg, adc.record_length)
                mzi_s = (samples[:, cfgd.channels.index("mzi"), :].reshape(bp, avg, adc.record_length)
                         if pn_on else None)
                t_pix = (t_ns.reshape(bp, avg)[:, 0] - hw_t0) * 1e-9
                # a clipped beat puts harmonics and a wrong amplitude into the spectrum
                over = np.array([h.overrange for h in headers], dtype=np.int64).reshape(bp, avg) != 0
                clipped = over.any(axis=1)
                faults["overrange_segments"] += int(over.sum())
                faults["overrange_pixels"] += int(clipped.sum())
                if recorder[0] is not None:
                    recorder[0].add(samples, headers, t_pix, cfgd.channels)
                pending.append((beat, pixels[done:done + bp], t_pix, clipped, mzi_s))
                pending_bytes[0] += beat.nbytes * len(channels)
                done += bp
                hw_last = (t_ns[-1] - hw_t0) * 1e-9 + adc.record_length / adc.fs_hz
                if pending_bytes[0] >= BATCH_BYTES or done >= n_pix:
                    flush()
                progress(ScanProgress(done, n_pix, int(sum(len(c) for c in chunks)), hw_last))
        except ScanFailed:
            raise
        except Exception as exc:
            raise ScanFailed(f"{_device_of(exc)}: {type(exc).__name__}: {exc}", result()) from exc
        finally:
            if not stopped_safe:
                try:
                    self.fpsa.stop()
                finally:
                    try:
                        self._abort_digitizer(done, n_pix)
                    finally:
                        self._bring_down()
            else:
                try:
                    self.fpsa.stop()
                except Exception as exc:  # outputs are already safe; report, do not mask the stop
                    log.warning("fpsa stop after a safety stop failed: %s", exc)
                self._abort_digitizer(done, n_pix)
        return result()

    def _abort_digitizer(self, done: int, n_pix: int) -> None:
        # An acquisition left armed locks the digitizer's configuration for the next job.
        if done >= n_pix:
            return
        try:
            self.digitizer.abort()
        except Exception as exc:
            log.warning("digitizer abort after an early stop failed: %s", exc)

    def _resume(self, rest: np.ndarray, avg: int, adc: _AdcPlan, channels: tuple[str, ...] = ("beat",)):
        """Stop what is left of the run and start a new acquisition for the pixels ``rest``."""
        try:
            self.fpsa.stop()
        except Exception as exc:  # the restart below is what matters; it fails loudly if needed
            log.warning("fpsa stop before resume failed: %s", exc)
        self.digitizer.abort()
        self._run_pattern(rest, avg)
        cfgd = self.digitizer.configure(channels=channels, sample_rate_hz=adc.fs_hz,
                                        record_length=adc.record_length, segments=len(rest) * avg,
                                        bits=adc.bits, input_range_v=self.cfg.adc.input_range_v)
        self.digitizer.arm()
        self.fpsa.arm()
        self.fpsa.start()
        return cfgd

    def _read_batch(self, first: int, count: int, cfgd, faults: dict[str, Any]):
        """Read one batch of segments; transient failures re-read the whole batch (bounded)."""
        last: Exception | None = None
        for attempt in range(BATCH_RETRIES + 1):
            if attempt:
                faults["batch_retries"] += 1
                delay = BATCH_BACKOFF_S * 2 ** (attempt - 1)
                log.warning("digitizer: re-reading segments %d..%d (attempt %d/%d) after %s",
                            first, first + count - 1, attempt + 1, BATCH_RETRIES + 1, last)
                self._sleep(delay)
            try:
                return self.digitizer.read_segments(first, count, cfgd)
            except DeviceStall as exc:
                raise InstrumentError(f"digitizer: refused READ_SEGMENTS({first},{count}): {exc}") from exc
            except DeviceDisconnected as exc:
                last = exc
                try:
                    self.digitizer.reconnect(f"READ_SEGMENTS({first},{count})")
                except Exception as exc2:
                    last = exc2
            except (UsbTimeout, UsbDeviceError) as exc:
                last = exc
        raise InstrumentError(f"digitizer: segments {first}..{first + count - 1} could not be read after "
                              f"{BATCH_RETRIES + 1} attempts: {type(last).__name__}: {last}") from last

    def _safety_trip(self) -> str | None:
        """One Modbus request: None when the interlock is closed and no fault is latched."""
        try:
            flags = self.controller.flags()
        except Exception as exc:
            # cannot see the interlock: treat as unsafe (fail safe)
            return f"controller: interlock state unreadable ({type(exc).__name__}: {exc})"
        if not flags.interlock_closed:
            return "controller: interlock opened mid-scan"
        if flags.fault_active:
            try:
                names = sorted(f.name for f in self.controller.faults())
            except Exception:
                names = ["unknown"]
            return f"controller: fault latched mid-scan ({', '.join(names)})"
        return None

    def _safe_state(self) -> dict[str, Any]:
        """Laser off and HV off commanded FIRST, then both read back; returns the readbacks."""
        errors = []
        for what, fn in (("laser off", lambda: self.controller.laser_enable(False)),
                         ("HV off", lambda: self.controller.hv_enable(False))):
            try:
                fn()
            except Exception as exc:
                errors.append(f"{what}: {type(exc).__name__}: {exc}")
        t_cmd = float(self._now())      # read after the commands: nothing may delay them
        try:
            self.controller.bring_down(settle_check=self._settle())
        except Exception as exc:
            errors.append(f"bring down: {type(exc).__name__}: {exc}")
        out: dict[str, Any] = {"off_commanded_at_s": t_cmd}
        try:
            out["laser_ma"] = float(self.controller.laser_current_ma())
            out["hv_v"] = float(self.controller.hv_v())
            out["laser_on"] = bool(self.controller.laser_is_on())
            out["hv_on"] = bool(self.controller.hv_is_on())
        except Exception as exc:
            errors.append(f"readback: {type(exc).__name__}: {exc}")
        out["safe_at_s"] = float(self._now())
        out["errors"] = errors
        out["safe"] = (not errors and not out.get("laser_on") and not out.get("hv_on")
                       and out.get("laser_ma", 1.0) <= 0.5 and out.get("hv_v", 1.0) <= 0.25)
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
        lin_faults: dict[str, Any] = {"batch_retries": 0}
        try:
            def measure(drive_v: np.ndarray, n_avg: int) -> np.ndarray:
                self._load_drive(drive_v)
                self._run_pattern(centre, n_avg)
                self.digitizer.abort()
                cfgd = self.digitizer.configure(channels=("mzi",), sample_rate_hz=fs, record_length=2 * r,
                                                segments=n_avg, bits=bits, input_range_v=self.cfg.adc.input_range_v)
                self.digitizer.arm()
                self.fpsa.arm()
                self.fpsa.start()
                _, samples = self._read_batch(0, n_avg, cfgd, lin_faults)
                self.fpsa.stop()
                reason = self._safety_trip()
                if reason is not None:
                    # the same safe path as a scan: outputs first, then give up the calibration
                    safe = self._safe_state()
                    raise InstrumentError(f"linearization stopped: {reason}; {_describe_safe(safe)}")
                history.append({})
                if progress is not None:
                    progress({"measurements": len(history)})
                return samples[:, 0, :].astype(np.float64)

            res = ilc_linearize(measure, self._plain_drive(), fs_drive_hz=AWG_RATE_HZ, fs_adc_hz=fs,
                                ramp_s=c.ramp_s, excursion_hz=c.excursion_hz, mzi_delay_s=tau_m, averages=32,
                                max_averages=512,
                                max_drive_v=self.cfg.devices.awg.max_output_v)
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

    # -- self-test -------------------------------------------------------------------------------------
    def selftest(self, progress: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
        with self._lock:
            return self._selftest(progress)

    def _selftest(self, progress) -> dict[str, Any]:
        """Toggle every bonded row (partner: one fixed column) and every column (partner: one fixed
        row) through a pattern, one pixel per line, and read the monitor "tap" (DC photodiode on the
        light leaving the chip, proportional to the number of emitting beams).

        Each reading becomes a beam count ``n = round(v / v1)`` with ``v1`` the single-beam level
        (median of the lowest cluster). A healthy line gives 1. A line reading 0 while its family
        reads >= 1 is stuck OFF. A stuck-ON line adds a beam to every OTHER measurement of its own
        family and of the other family, so the family reads 2 while the stuck line itself reads 1:
        a line reading fewer beams than its family's majority (but not 0) is stuck ON. A family that
        reads 0 throughout blames its fixed partner (stuck off).
        """
        bonded = [int(r) for r in self.optics.bonded_rows]
        cols = list(range(int(self.optics.cols)))
        r0 = bonded[len(bonded) // 2]
        c0 = cols[len(cols) // 2]
        pixels = np.array([(r, c0) for r in bonded] + [(r0, c) for c in cols], dtype=np.int64)
        n = len(pixels)
        fs = float(self.cfg.adc.min_sample_rate_hz) if self.cfg.adc.min_sample_rate_hz else 10e6
        rec = 64
        bits = 16
        if progress is not None:
            progress({"stage": "preparing", "lines": n})
        self._bring_up()
        try:
            self._load_drive(self._plain_drive())
            self._run_pattern(pixels, 1)
            self.digitizer.abort()
            cfgd = self.digitizer.configure(channels=("tap",), sample_rate_hz=fs, record_length=rec,
                                            segments=n, bits=bits, input_range_v=self.cfg.adc.input_range_v)
            self.digitizer.arm()
            self.fpsa.arm()
            self.fpsa.start()
            faults: dict[str, Any] = {"batch_retries": 0}
            volts = np.zeros(n)
            lsb = self.cfg.adc.input_range_v / 2 ** bits
            step = 256
            for first in range(0, n, step):
                cnt = min(step, n - first)
                _, samples = self._read_batch(first, cnt, cfgd, faults)
                volts[first:first + cnt] = samples[:, 0, :].astype(np.float64).mean(axis=1) * lsb
                if progress is not None:
                    progress({"stage": "measuring", "done": first + cnt, "lines": n})
            reason = self._safety_trip()
            if reason is not None:
                raise InstrumentError(f"self-test stopped: {reason}")
        finally:
            try:
                self.fpsa.stop()
            finally:
                self._bring_down()
        return analyse_selftest(volts[:len(bonded)], volts[len(bonded):], bonded, cols, r0, c0)

    # -- simulation ------------------------------------------------------------------------------------
    def _hooks(self, what: str) -> SimHooks:
        if self._sim is None:
            raise NotSimulated(f"{what}: the instrument is real hardware; only a simulated bench has this")
        return self._sim

    def set_scene(self, scene: dict[str, Any]) -> dict[str, Any]:
        """Simulation only: replace the bench's scene (the scene-file structure as a dict).

        Returns ``{"name", "targets"}``; a scene the bench refuses raises :class:`SceneRejected`
        naming what is wrong (the bench parses it: the daemon side does not know the scene format).
        """
        if self._set_scene is None:
            raise NotSimulated("set_scene: only a simulated bench has a scene")
        return self._set_scene(scene)

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


def analyse_selftest(row_v: np.ndarray, col_v: np.ndarray, rows: list[int], cols: list[int],
                     r0: int, c0: int) -> dict[str, Any]:
    """Beam counts and stuck lines from the tap readings (see LidarInstrument._selftest)."""
    row_v = np.asarray(row_v, np.float64)
    col_v = np.asarray(col_v, np.float64)
    allv = np.concatenate([row_v, col_v])
    top = float(np.max(allv)) if allv.size else 0.0
    lit = allv[allv > 0.3 * top] if top > 0 else allv[:0]
    if lit.size == 0:
        v1 = float("nan")
    else:
        low = lit[lit < 1.5 * lit.min()]
        v1 = float(np.median(low))
    stuck: list[dict[str, Any]] = []
    counts = {}
    for fam, volts, lines, partner in (("row", row_v, rows, ("col", c0)), ("col", col_v, cols, ("row", r0))):
        if not np.isfinite(v1) or v1 <= 0:
            n = np.zeros(len(volts), np.int64)
        else:
            n = np.rint(volts / v1).astype(np.int64)
        counts[fam] = n
        majority = int(np.bincount(np.clip(n, 0, None)).argmax()) if len(n) else 0
        if majority == 0:
            stuck.append({"line": partner[0], "index": int(partner[1]), "state": "off",
                          "evidence": f"every {fam} read dark with this fixed partner"})
            continue
        for i, k in enumerate(n):
            if k == 0:
                stuck.append({"line": fam, "index": int(lines[i]), "state": "off",
                              "evidence": f"tap {volts[i]:.4g} V, no beam (family reads {majority})"})
            elif majority >= 2 and k < majority:
                stuck.append({"line": fam, "index": int(lines[i]), "state": "on",
                              "evidence": f"tap {volts[i]:.4g} V = {k} beam(s) while the other {fam}s read "
                                          f"{majority}: this line's extra beam is always there"})
    return {"ok": not stuck, "stuck": stuck, "single_beam_v": v1, "partner_row": int(r0), "partner_col": int(c0),
            "rows_tested": len(rows), "cols_tested": len(cols),
            "row_tap_v": [float(v) for v in row_v], "col_tap_v": [float(v) for v in col_v]}


def _describe_safe(safe: dict[str, Any]) -> str:
    if safe.get("safe"):
        return (f"laser and HV brought down and read back (laser {safe['laser_ma']:.2f} mA, "
                f"HV {safe['hv_v']:.2f} V)")
    return "SAFE STATE NOT CONFIRMED: " + "; ".join(safe.get("errors") or ["readback out of tolerance"])


def _device_of(exc: BaseException) -> str:
    dev = getattr(exc, "device", None)
    if isinstance(dev, str) and dev:
        return dev
    mod = type(exc).__module__ or ""
    for name in ("fpsa", "awg", "digitizer", "controller"):
        if f"drivers.{name}" in mod:
            return name
    return "instrument"


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
def _usb_ids(spec: str, default_ids: tuple[int, int], who: str) -> tuple[int, int]:
    if spec == "bench":
        return default_ids
    try:
        vid_s, pid_s = spec.split(":")
        return int(vid_s, 16), int(pid_s, 16)
    except ValueError:
        raise InstrumentError(f"{who}: usb address {spec!r} is not VID:PID (hex)") from None


def _usb_finder(backend, ids: tuple[int, int]):
    import usb.core

    def find():
        return usb.core.find(idVendor=ids[0], idProduct=ids[1], backend=backend)
    return find


def _usb_device(backend, spec: str, default_ids: tuple[int, int], who: str):
    ids = _usb_ids(spec, default_ids, who)
    dev = _usb_finder(backend, ids)()
    if dev is None:
        raise InstrumentError(f"{who}: no USB device {ids[0]:04x}:{ids[1]:04x} found")
    return dev


def _connect(cfg: Config, endpoints: dict[str, Any] | None, usb_backend, sleep) -> dict[str, Any]:
    from drivers.awg import protocol as awg_p
    from drivers.digitizer import protocol as dig_p

    d = cfg.devices
    fpsa_url = endpoints["fpsa_url"] if endpoints and d.fpsa.url == "bench" else d.fpsa.url
    host = endpoints["controller_host"] if endpoints and d.controller.host == "bench" else d.controller.host
    port = endpoints["controller_port"] if endpoints and d.controller.host == "bench" else d.controller.port
    # Backoffs go through ``sleep`` (the virtual clock on a bench) so a device that comes back after
    # some virtual time is found again without any wall-clock wait.
    fpsa = FpsaController(fpsa_url, timeout_s=d.fpsa.timeout_s, baudrate=d.fpsa.baudrate, sleep=sleep)
    ctrl = LaserHvController(host, port, device_id=d.controller.device_id, timeout_s=d.controller.timeout_s,
                             limits=Limits(max_laser_current_ma=d.controller.max_laser_current_ma,
                                           max_hv_v=d.controller.max_hv_v, tec_range_c=(15.0, 40.0)),
                             sleep=sleep, busy_retries=3)
    awg_ids = _usb_ids(d.awg.usb, (awg_p.AWG_VID, awg_p.AWG_PID), "awg")
    dig_ids = _usb_ids(d.digitizer.usb, (dig_p.DIGITIZER_VID, dig_p.DIGITIZER_PID), "digitizer")
    awg = AwgDriver(_usb_device(usb_backend, d.awg.usb, awg_ids, "awg"),
                    finder=_usb_finder(usb_backend, awg_ids), sleep=sleep)
    dig = DigitizerDriver(_usb_device(usb_backend, d.digitizer.usb, dig_ids, "digitizer"),
                          finder=_usb_finder(usb_backend, dig_ids), sleep=sleep)
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

        from sim_devices.world.scene import SceneError

        def set_scene(d: dict) -> dict:
            try:
                scene = _Scene.from_dict(d, source="<request>")
            except SceneError as exc:
                raise SceneRejected(str(exc)) from None
            b.set_scene(scene)
            return {"name": scene.name, "targets": len(scene)}

        hooks = SimHooks(set_scene=set_scene,
                         inject_fault=lambda kind, **params: b.inject_fault(kind, **params),
                         clear_faults=lambda kind=None: b.clear_faults(kind),
                         active_faults=lambda: b.active_faults())
        return LidarInstrument(cfg, simulated=True, sleep=b.clock.advance, now=b.clock.now, sim=hooks,
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
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=os.environ.copy())
    stderr_tail: collections.deque[str] = collections.deque(maxlen=20)

    def forward_stderr() -> None:   # the child's complaints go to our log, the last ones into errors
        for raw in proc.stderr:
            text = raw.decode("utf-8", "replace").rstrip()
            stderr_tail.append(text)
            log.warning("%s", text if text.startswith("lidar-sim") else f"lidar-sim: {text}")

    reader = threading.Thread(target=forward_stderr, name="lidar-sim-stderr", daemon=True)
    reader.start()
    line = proc.stdout.readline()
    if not line:
        proc.kill()
        reader.join(timeout=5)
        why = stderr_tail[-1] if stderr_tail else "no message"
        raise InstrumentError(f"simulated bench: the lidar-sim child process did not start: {why}")
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

    def call(cmd: str, **kw) -> dict:
        try:
            return ctl.call(cmd, **kw)
        except ValueError as exc:   # the bench refused (unknown kind, bad parameter): say so
            raise SimFaultError(str(exc)) from None

    def set_scene(d: dict) -> dict:
        try:
            reply = ctl.call("set_scene", scene=d)
        except ValueError as exc:   # the bench's SceneError, named
            raise SceneRejected(str(exc)) from None
        return {"name": reply.get("name"), "targets": int(reply.get("targets", 0))}

    hooks = SimHooks(set_scene=set_scene,
                     inject_fault=lambda kind, **params: call("inject", kind=kind, **params)["fault"],
                     clear_faults=lambda kind=None: int(call("clear_faults", kind=kind)["cleared"]),
                     active_faults=lambda: call("faults")["faults"])
    parts = _connect(cfg, ep, backend_from_url(ep["usb_url"]), advance)
    return LidarInstrument(cfg, simulated=True, sleep=advance, now=lambda: float(ctl.call("ping")["t_s"]),
                           sim=hooks, on_close=stop_child, **parts)
