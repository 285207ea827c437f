"""The simulated bench: one world, one virtual clock, every simulated instrument (`lidar-sim`).

Wires the byte-level peers to one :class:`~sim_devices.world.world.World` (scene, optics, link
budget), one DFB laser model and one :class:`~sim_devices.clock.VirtualClock`:

* the FPGA (``sim_devices.fpga``, served on a pty) steps the uploaded pattern and decides, per
  trigger, which pixel is commanded and which beams actually leave the chip (MEMS dynamics, §4.3.6);
* the AWG (USBTMC over the pyusb backend) holds the drive waveform that the laser model turns into
  nu(t) (the trajectory is computed once per waveform and laser temperature, to 1 mK, and cached; the
  temperature is the laser chip's TRUE one, which the controller's TEC readback does not show:
  sim_devices.world.tec);
* the controller (Modbus TCP) gates the light: no laser output unless the laser is on and the
  interlock closed, no switch actuation unless the HV output is above the switches' pull-in voltage;
* the digitizer (vendor bulk protocol over the pyusb backend) asks this bench, as its
  ``SegmentSource``, for the segments it streams: triggers from the FPGA, beams -> hits -> beat
  tones from the world, synthesized at the sample rate the host configured (never a fixed high rate).
  A record resolution the host configured wider than the converter core (``CaptureConfig.
  resolution_bits``; 16-bit-format records from the 8-bit core of Table 2-2, config.Adc.record_bits)
  models on-board decimation from the core's full rate: the core's quantization noise is added as
  white noise over its full Nyquist band, then the digitizer band-limits the record and rounds it to
  the configured resolution.

Each trigger starts one period (up + down ramp) of the AWG waveform, so every segment's record starts
at t = 0 of the drive period. Segment noise is seeded from (bench seed, run, first segment index), so a
re-read of the same batch gives the same bytes.

Modes: in-process (``Bench(...).start(usb="inproc")``, the embedded default of ``lidarctl scan --sim``)
or as its own process (``lidar-sim --json``: prints its endpoints as one JSON line and serves until
stdin closes or it gets SIGTERM), with the USB transfers carried over a local socket and a small JSON
control socket (set_scene, set_interlock, advance, ground_truth, truth, ping, inject, clear_faults,
faults, fidelity: the ledger of modelled / skipped effects).

Hidden truths (issue 13, :mod:`sim_devices.world.tolerances`): the bench draws, from
``[sim.tolerances]`` and its seed, the monitor MZI's true delay (used for the monitor fringes
instead of the configured ``monitor.delay_s``), the range zero offset and the true pointing (both
in the world). ``Bench.truth()`` and the control command ``truth`` give them to tests and
benchmarks; the daemon has only the nominal configuration.

The FPGA's serial port is published as a STABLE path, a symlink in the bench's temp dir (like
``/dev/serial/by-id/...``) that points at the current pty slave: after a ``serial_disconnect`` fault
is cleared the FPGA comes back on a NEW pty and the symlink is re-pointed, so a driver reopens the
same ``fpsa_url``.

Fault injection (issue 6; catalogue and parameters in ``sim_devices.faults``):
``inject_fault(kind, **params) -> dict``, ``clear_faults(kind=None) -> int``, ``active_faults()``;
``[[sim.faults]]`` tables of the configuration are injected by :meth:`Bench.start`. Faults of the
kinds ``serial_drop``, ``serial_flip``, ``digitizer_overrange``, ``hv_fault``, ``serial_disconnect``,
``interlock_open`` and ``tec_offset`` are one per bench: injecting one again replaces the earlier one (its ``id``
changes). Count-limited faults (``n``) drop out of ``active_faults()`` once used up.

Tap channel (self-test): digitizer channel ``tap`` is a monitor photodiode on the light leaving the
FPSA: V = G_tap R eta_tap P_tx sum_beams T_beam (+ white detector noise), where P_tx is the power
one fully-open path emits (the link's P_tx), T_beam the mean switch-path transmission of every beam
that actually emits in the capture window (MEMS states incl. stuck switches): one beam for a
healthy pixel, two when a row or column line is stuck on, none when one is stuck off.

This module is a composition root of the simulator; like the world it reads ``lidard.config``.
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import os
import shutil
import signal
import socket
import sys
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.controller import protocol as ctl_p
from lidard.config import Config, ConfigError, load_config
from lidard.physics.budget import monitor_noise_asd, quantization_asd

from .awg import SimAwg
from .clock import VirtualClock
from .controller import ControllerSim
from .digitizer import CaptureConfig, CapturedSegments, SimDigitizer, decimation_filter
from .faults import FAULT_KINDS, SerialLineNoise, validate_fault
from .fpga import FpgaConfig, FpgaSim
from .hv_drive import HvDrive
from .usb_backend import SimUsbBackend, UsbBridgeServer
from .world.fidelity import FidelityLedger, phase_noise_negligible
from .world.laser import DfbLaser
from .world.tec import from_tolerances as tec_model
from .world.mems import SwitchDynamics
from .world.scene import Scene, SceneError
from .world.synth import AdcSpec, HitBatch, synthesize, trajectory
from .world.tolerances import BenchTruth, draw_truth
from .world.world import World


@dataclass(frozen=True)
class TapSpec:
    """Monitor photodiode on the FPSA's emission (the digitizer's ``tap`` channel)."""

    fraction: float = 0.01          # 1 % tap coupler on the emitted light
    gain_v_per_a: float = 1.0e4     # monitor TIA
    noise_v_rms: float = 1.0e-3     # white detector + TIA noise per sample


# Faults of which a bench holds at most one: a second injection replaces the first.
_SINGLETONS = ("serial_drop", "serial_flip", "serial_disconnect", "digitizer_overrange", "hv_fault",
               "interlock_open", "tec_offset")
_USB_KIND = {"usb_timeout": "timeout", "usb_stall": "stall", "usb_disconnect": "disconnect"}


class Bench:
    """Every simulated device around one world and one virtual clock."""

    def __init__(self, cfg: Config, scene: Scene | None = None, *, seed: int | None = None) -> None:
        self.cfg = cfg
        for i, entry in enumerate(cfg.sim.faults):   # fail before anything starts, naming the entry
            params = {k: v for k, v in entry.items() if k != "kind"}
            try:
                validate_fault(entry.get("kind"), params)
            except ValueError as exc:
                raise ConfigError(f"{cfg.source}: sim.faults: entry {i}: {exc}") from None
        self.profile = cfg.load_profile()
        self.laser_preset = cfg.load_laser()
        if scene is None:
            scene = Scene.from_toml(cfg.resolve_path(cfg.sim.scene))
        self.seed = cfg.sim.seed if seed is None else int(seed)
        self.clock = VirtualClock()
        # the hidden truths (issue 13): drawn once, never told to the daemon
        self._truth = draw_truth(cfg.sim.tolerances, nominal_mzi_delay_s=cfg.monitor.delay_s, seed=self.seed)
        self.world = World(cfg, self.profile, self.laser_preset, scene, seed=self.seed, truth=self._truth)
        self.laser = DfbLaser(self.laser_preset)
        pr = self.profile
        row_dyn, col_dyn = (SwitchDynamics(sw.on_s, sw.off_s, pull_in_v=pr.pull_in_v,
                                           release_v=pr.release_v, discharge_rc_s=pr.discharge_rc_s)
                            for sw in (pr.row_switch, pr.col_switch))
        self.fpga = FpgaSim(self.clock, FpgaConfig(
            rows=pr.rows, cols=pr.cols, bonded_rows=pr.bonded_rows,
            baudrate=cfg.devices.fpsa.baudrate, hv_supply_v=pr.actuation_v, seed=self.seed,
            row_dynamics=row_dyn, col_dynamics=col_dyn, threshold_spread_v=pr.threshold_spread_v))
        self.awg = SimAwg()
        self.digitizer = SimDigitizer(self.clock, source=self)
        # the laser's true temperature moves its chirp (issue 13; sim_devices.world.tec)
        self.tec_tuning, tec_drift = tec_model(cfg.sim.tolerances, self.seed)
        self.controller = ControllerSim(self.clock, tec_drift=tec_drift)
        self.fpga.supply = self._hv_drive  # the controller's HV is the HV583 supply rail
        self._traj_key: bytes | None = None
        self._traj = None
        self._lock = threading.RLock()
        self._pty = None
        self._bridge: UsbBridgeServer | None = None
        self._control: _ControlServer | None = None
        self.usb_backend = None
        self.segments_synthesized = 0
        # FPGA run start (virtual s) -> 1, 2, ... in the order runs are first captured: the noise seed
        # (see _run_index)
        self._run_ids: dict[float, int] = {}
        self.fidelity = FidelityLedger()  # which effects each captured batch modelled or skipped
        self.tap = TapSpec()
        # Serial line noise seeded from the bench seed: a run with faults repeats byte for byte.
        self.serial_line = SerialLineNoise((self.seed, 0x5E71A1))
        self._tmpdir: str | None = None
        self.fpsa_link: str | None = None
        self._faults: dict[int, dict[str, Any]] = {}
        self._fault_ids = itertools.count(1)
        self._fault_lock = threading.RLock()
        self._timers: dict[int, int] = {}          # fault id -> clock timer handle
        self._overrange_gain = 1.0
        self._interlock_at_s: float | None = None      # a timed opening not yet reached
        self._interlock_after: int | None = None       # open when segments_synthesized reaches this
        self._interlock_fid: int | None = None

    # -- lifecycle ----------------------------------------------------------------------------------
    def start(self, *, usb: str = "inproc", control: bool = False) -> dict[str, Any]:
        """Serve the FPGA on a pty, the controller on Modbus TCP and the USB devices; apply the
        configuration's ``[[sim.faults]]``; return endpoints."""
        self._tmpdir = tempfile.mkdtemp(prefix="lidard-bench-")
        self.fpsa_link = os.path.join(self._tmpdir, "fpsa")
        self._open_pty()
        self.controller.start()
        if usb == "inproc":
            self.usb_backend = SimUsbBackend([self.awg, self.digitizer])
            usb_url = "sim-usb://inproc"
        elif usb == "tcp":
            self._bridge = UsbBridgeServer([self.awg, self.digitizer])
            usb_url = self._bridge.url
        else:
            raise ValueError(f"Bench.start: usb must be 'inproc' or 'tcp', got {usb!r}")
        if control:
            self._control = _ControlServer(self)
        for entry in self.cfg.sim.faults:
            entry = dict(entry)
            self.inject_fault(entry.pop("kind", None), **entry)
        return self.endpoints(usb_url)

    def endpoints(self, usb_url: str | None = None) -> dict[str, Any]:
        return {
            "fpsa_url": self.fpsa_link,
            "controller_host": self.controller.host,
            "controller_port": self.controller.port,
            "usb_url": usb_url or (self._bridge.url if self._bridge else "sim-usb://inproc"),
            "control_port": self._control.port if self._control else None,
        }

    def close(self) -> None:
        for handle in list(self._timers.values()):
            self.clock.cancel(handle)
        self._timers.clear()
        for thing in (self._control, self._bridge, self._pty):
            if thing is not None:
                try:
                    thing.close()
                except Exception:  # closing must go on for the others
                    pass
        try:
            self.controller.stop()
        except Exception:
            pass
        if self._tmpdir is not None:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            self._tmpdir = None

    # -- the FPGA's serial port behind a stable path ------------------------------------------------
    def _open_pty(self) -> None:
        self._pty = self.fpga.serve_pty(self.serial_line)
        assert self.fpsa_link is not None
        tmp = self.fpsa_link + ".new"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(self._pty.path, tmp)
        os.replace(tmp, self.fpsa_link)  # atomic: a reader sees the old or the new target

    def _drop_pty(self) -> None:
        if self._pty is not None:
            self._pty.close()
            self._pty = None
        if self.fpsa_link is not None and os.path.lexists(self.fpsa_link):
            os.unlink(self.fpsa_link)  # the device node vanishes, as /dev/serial/by-id/* does
        self.fpga.reset_link()

    # -- fault injection ------------------------------------------------------------------------------
    def inject_fault(self, kind: str, **params: Any) -> dict[str, Any]:
        """Inject a fault (catalogue: ``sim_devices.faults``); returns it as a dict with an ``id``.

        Raises ``ValueError`` naming the kind or parameter if it is unknown or bad (nothing is
        changed then)."""
        spec = validate_fault(kind, params)
        with self._fault_lock:
            if kind == "stuck_switch":
                n = self.profile.rows if spec["line"] == "row" else self.profile.cols
                if spec["index"] >= n:
                    raise ValueError(f"fault stuck_switch: index must be 0..{n - 1} for a "
                                     f"{spec['line']}, got {spec['index']}")
            if kind in _SINGLETONS:
                for fid, rec in list(self._faults.items()):
                    if rec["kind"] == kind:
                        self._undo(fid, rec, replacing=True)
            fid = next(self._fault_ids)
            rec = {"id": fid, **spec, "since_s": self.clock.now()}
            self._faults[fid] = rec
            self._apply(fid, rec)
            return dict(rec)

    def clear_faults(self, kind: str | None = None) -> int:
        """Clear active faults of ``kind`` (all if None) and restore normal behaviour; returns
        how many were cleared."""
        if kind is not None and kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {kind!r}; known: {', '.join(FAULT_KINDS)}")
        with self._fault_lock:
            self._prune()
            n = 0
            for fid, rec in list(self._faults.items()):
                if kind is None or rec["kind"] == kind:
                    self._undo(fid, rec)
                    n += 1
            return n

    def active_faults(self) -> list[dict[str, Any]]:
        with self._fault_lock:
            self._prune()
            return [dict(r) for r in self._faults.values()]

    def _usb_device(self, name: str):
        return self.awg if name == "awg" else self.digitizer

    def _prune(self) -> None:
        """Forget count-limited faults whose count is used up (their effect is over)."""
        for fid, rec in list(self._faults.items()):
            k = rec["kind"]
            done = False
            if k in _USB_KIND and rec["n"] is not None:
                dev = self._usb_device(rec["device"])
                if k == "usb_disconnect":
                    done = dev.connected
                else:
                    done = not any(f[0] == _USB_KIND[k] for f in dev._faults)
            elif k == "modbus_exception" and rec["n"] is not None:
                done = not self.controller._pending_exceptions
            elif k == "modbus_timeout" and rec["n"] is not None:
                done = self.controller._pending_timeouts == 0
            if done:
                del self._faults[fid]

    def _apply(self, fid: int, rec: dict[str, Any]) -> None:
        k = rec["kind"]
        if k == "serial_drop":
            self.serial_line.drop_rate = rec["rate"]
        elif k == "serial_flip":
            self.serial_line.flip_rate = rec["rate"]
        elif k == "serial_disconnect":
            self._drop_pty()
            if rec["reconnect_after_s"] is not None:
                self._timers[fid] = self.clock.call_at(
                    rec["since_s"] + rec["reconnect_after_s"], lambda: self._expire(fid))
        elif k in _USB_KIND:
            dev = self._usb_device(rec["device"])
            if k == "usb_disconnect":
                dev.disconnect(rec["n"])
            else:
                dev.inject_fault(_USB_KIND[k], "any", rec["n"])
        elif k == "digitizer_overrange":
            self._overrange_gain = rec["gain"]
        elif k == "modbus_exception":
            self.controller.inject_exception(rec["code"], rec["n"])
        elif k == "modbus_timeout":
            self.controller.inject_timeout(rec["n"])
        elif k == "interlock_open":
            self._interlock_fid = fid
            now = self.clock.now()
            if rec["after_segments"] is not None:
                self._interlock_after = self.segments_synthesized + rec["after_segments"]
            elif rec["at_s"] is not None and rec["at_s"] > now:
                self._interlock_at_s = rec["at_s"]
                self._timers[fid] = self.clock.call_at(rec["at_s"], self._open_interlock)
            else:
                self._open_interlock()
        elif k == "stuck_switch":
            self.fpga.stick_switch(rec["line"], rec["index"], rec["state"] == "on")
        elif k == "hv_fault":
            self.controller.set_fault_cause(ctl_p.Fault.HV_FAULT, True)
        elif k == "tec_offset":
            self.controller.model.tec_offset_c = rec["offset_c"]

    def _undo(self, fid: int, rec: dict[str, Any], *, replacing: bool = False) -> None:
        self._faults.pop(fid, None)
        handle = self._timers.pop(fid, None)
        if handle is not None:
            self.clock.cancel(handle)
        k = rec["kind"]
        if k == "serial_drop":
            self.serial_line.drop_rate = 0.0
        elif k == "serial_flip":
            self.serial_line.flip_rate = 0.0
        elif k == "serial_disconnect":
            if self._pty is None and self.fpsa_link is not None:
                self._open_pty()
        elif k in _USB_KIND:
            dev = self._usb_device(rec["device"])
            if k == "usb_disconnect":
                dev.reconnect()
            else:
                dev.clear_faults(_USB_KIND[k])
        elif k == "digitizer_overrange":
            self._overrange_gain = 1.0
        elif k == "modbus_exception":
            self.controller.clear_injected("exception")
        elif k == "modbus_timeout":
            self.controller.clear_injected("timeout")
        elif k == "interlock_open":
            self._interlock_at_s = self._interlock_after = self._interlock_fid = None
            if not replacing:
                self.controller.set_interlock(True)
        elif k == "stuck_switch":
            self.fpga.release_switch(rec["line"], rec["index"])
        elif k == "hv_fault":
            self.controller.set_fault_cause(ctl_p.Fault.HV_FAULT, False)
        elif k == "tec_offset":
            self.controller.model.tec_offset_c = 0.0

    def _expire(self, fid: int) -> None:
        """A fault that ends by itself (``reconnect_after_s``)."""
        with self._fault_lock:
            rec = self._faults.get(fid)
            if rec is not None:
                self._timers.pop(fid, None)
                self._undo(fid, rec)

    def _open_interlock(self) -> None:
        self._interlock_at_s = None
        self._interlock_after = None
        self.controller.set_interlock(False)

    def _hv_drive(self) -> HvDrive:
        st = self.controller.state
        return HvDrive(st.hv_v if st.hv_on else 0.0, st.hv_hold_setpoint_v if st.hv_on else 0.0)

    # -- world control ------------------------------------------------------------------------------
    def set_scene(self, scene: Scene) -> None:
        with self._lock:
            self.world.set_scene(scene)

    def ground_truth(self, rows, cols, t_s=None, measured_m=None) -> np.ndarray:
        """First-hit range per pixel; ``t_s``: scene time per pixel (a point's ``t``) for moving targets;
        ``measured_m``: score mixed pixels against their footprint's nearest return (World.ground_truth)."""
        with self._lock:
            return self.world.ground_truth(rows, cols, t_s, measured_m)

    def mixed_pixels(self, rows, cols) -> np.ndarray:
        """True per pixel where the footprint crosses a target outline (weighted returns)."""
        with self._lock:
            return self.world.is_mixed(rows, cols)

    def _run_first_trigger_s(self) -> float:
        sched = self.fpga.schedule
        return 0.0 if sched is None else float(sched.trigger_s(np.array([0]))[0])

    def truth(self) -> BenchTruth:
        """The bench's hidden true values (sim_devices.world.tolerances): for tests and benchmarks
        only, never for the daemon."""
        return self._truth

    # -- SegmentSource ------------------------------------------------------------------------------
    def _trajectory(self):
        drive, fs = self.awg.drive_volts()
        if not self.awg.output_on:
            drive = np.zeros_like(drive)
        laser, temp_c = self.laser, None
        if self.tec_tuning is not None:   # keyed on the 1 mK grid: not recomputed every batch
            temp_c = self.tec_tuning.quantise(self.controller.model.laser_temperature_c())
            laser = self.tec_tuning.laser_at(self.laser, temp_c)
        key = hashlib.sha1(np.ascontiguousarray(drive).tobytes() + repr((float(fs), temp_c)).encode()).digest()
        if key != self._traj_key:
            self._traj = trajectory(laser, drive, fs)
            self._traj_key = key
        return self._traj

    def _interlock_cut_s(self, t_s: np.ndarray) -> float | None:
        """Trigger time from which an interlock opening darkens this batch (None: it does not)."""
        with self._fault_lock:
            if self._interlock_after is not None and len(t_s):
                k = self._interlock_after - self.segments_synthesized
                if k < len(t_s):
                    cut = float(t_s[max(k, 0)])
                    self._open_interlock()  # the loop opens now: later batches see it tripped
                    return cut
            if self._interlock_at_s is not None and len(t_s) and t_s[-1] >= self._interlock_at_s:
                return self._interlock_at_s  # the clock timer trips the controller at at_s
            return None

    def _tap_codes(self, path_sum: np.ndarray, adc: AdcSpec, first: int):
        """Monitor photodiode codes: a DC level per segment (sum of emitting path transmissions)
        plus white noise, quantized like every channel; clipped segments are flagged."""
        volts_per_path = self.tap_volts_per_beam()
        rng = np.random.default_rng([self.seed, 0x7A9, int(first)])
        v = (volts_per_path * path_sum)[:, None] + self.tap.noise_v_rms * rng.standard_normal(
            (path_sum.size, adc.n_samples))
        lo_code, hi_code = -(2 ** (adc.bits - 1)), 2 ** (adc.bits - 1) - 1
        raw = np.rint(v / adc.lsb_v)
        over = (raw < lo_code).any(axis=1) | (raw > hi_code).any(axis=1)
        return np.clip(raw, lo_code, hi_code).astype(np.int16), over

    def _core_asd(self, capture: CaptureConfig) -> float:
        """White-noise ASD of the converter core's quantization in a decimated record.

        The simulated converter is the one the configuration describes (``adc.bits`` at
        ``adc.max_sample_rate_hz``). A record the host configured wider than the core
        (``CaptureConfig.resolution_bits`` > core bits: config.Adc.record_bits, core bits + the
        decimation gain + guard bits) was decimated on board, so the core's quantization noise,
        LSB^2/12 over its full Nyquist band, is in it as white noise; the digitizer then rounds the
        record to the configured resolution. A record at the core's own resolution gets only that
        rounding."""
        a = self.cfg.adc
        if int(capture.resolution_bits) <= a.bits:
            return 0.0
        return quantization_asd(a.input_range_v, a.bits, a.max_sample_rate_hz)

    def _monitor_asd(self, capture: CaptureConfig) -> float:
        """White-noise ASD of the monitor-MZI channel: its photodiode's shot noise and the laser's
        RIN (``sim.effects.noise``), plus the decimated core's quantization noise (:meth:`_core_asd`,
        ``sim.effects.quantization``)."""
        eff, mon = self.cfg.sim.effects, self.cfg.monitor
        asd = 0.0
        if eff.noise:
            asd = monitor_noise_asd(mon.amplitude_v, mon.power_w, self.cfg.detector.responsivity_a_per_w,
                                    self.laser_preset.rin_db_per_hz)["total"]
        if eff.quantization:
            asd = float(np.hypot(asd, self._core_asd(capture)))
        return asd

    def tap_volts_per_beam(self) -> float:
        """Tap level of one fully open beam (what a healthy pixel reads), V."""
        link = self.world.link
        return (self.tap.gain_v_per_a * self.cfg.detector.responsivity_a_per_w * self.tap.fraction
                * link.source_power_w * link.tx_fraction)

    def _run_index(self) -> int:
        """Which captured run this is (0 before any run), for the noise seed.

        Not the run's virtual start time: the host's retry backoffs advance the virtual clock, and
        those depend on wall-clock timeouts (a loaded machine), so a seed from the start time gave
        different noise, a different ILC drive and different ranges from one run of the same
        programme to the next. The count of runs captured is the same however long they waited.
        """
        start = self.fpga.run_start_s
        if start is None:
            return 0
        return self._run_ids.setdefault(float(start), len(self._run_ids) + 1)

    def _phase_noise_linewidth(self, linewidth_hz: float, hits, want_mzi: bool, noise_asd: float) -> float:
        """The linewidth this batch is synthesized with: 0 when, for every hit, the beat's phase noise
        is below the bounds of :mod:`sim_devices.world.fidelity` and no monitor channel needs it."""
        if linewidth_hz <= 0:
            return 0.0
        c = self.cfg.chirp
        skip = not want_mzi and (hits is None or phase_noise_negligible(
            hits.tau_s, hits.amplitude_v, linewidth_hz, noise_asd, c.ramp_s, c.rate_hz_per_s))
        self.fidelity.note("phase_noise", not skip)
        return 0.0 if skip else linewidth_hz

    def capture(self, first: int, count: int, cfg: CaptureConfig) -> CapturedSegments:
        with self._lock:
            return self._capture(first, count, cfg)

    def _capture(self, first: int, count: int, cfg: CaptureConfig) -> CapturedSegments:
        eff = self.cfg.sim.effects
        capture_s = cfg.record_length / cfg.sample_rate_hz
        trig = self.fpga.triggers(first, count, capture_s)
        n = len(trig)
        st = self.controller.state
        light = bool(st.laser_on and st.interlock_closed)
        # the HV583 outputs carry the controller's HV: which switches pull in is the FPGA's
        # (per-switch hysteresis); an HV output switched off during a run still darkens it
        switches = bool(st.hv_on)
        # Light per segment: an interlock that opens inside this batch (at a virtual time or after
        # a number of segments) darkens the segments from that trigger on.
        lit = np.full(n, light)
        cut_s = self._interlock_cut_s(trig.t_s)
        if cut_s is not None:
            lit &= np.asarray(trig.t_s) < cut_s
        gain = self._overrange_gain
        iq = "beat_i" in cfg.channels
        adc = AdcSpec(sample_rate_hz=cfg.sample_rate_hz, n_samples=cfg.record_length, bits=cfg.bits,
                      input_range_v=cfg.input_range_v, iq=iq, quantize=True)
        hits = None
        # a stuck switch only shows through the switch dynamics (which beams actually emit)
        beams_from_dynamics = (eff.mems_dynamics or bool(self.fpga.stuck_switches)
                               or not self.fpga.pulls_in_every_switch())
        if beams_from_dynamics:
            rows, cols, trans, beam_seg = (trig.beam_row, trig.beam_col, trig.beam_transmission,
                                           np.asarray(trig.beam_trigger, np.intp))
        else:
            rows, cols, trans, beam_seg = trig.row, trig.col, np.ones(n), np.arange(n)
        emitting = lit[beam_seg] & switches
        if light and switches and n and emitting.any():
            chirp = np.asarray(trig.index)[np.asarray(beam_seg)[emitting]]
            # scene time: since the run's first trigger (a point's t counts from the same trigger)
            t_scene = np.asarray(trig.t_s)[np.asarray(beam_seg)[emitting]] - self._run_first_trigger_s()
            bh = self.world.beam_hits(rows[emitting], cols[emitting], trans[emitting], chirp=chirp, t_s=t_scene)
            if bh.beam.size:
                phase = None
                if bh.speckle_phase_rad is not None:  # others keep the synthesis' 2 pi nu0 tau
                    plain = 2.0 * np.pi * np.mod(self._trajectory().nu0_hz * bh.tau_s, 1.0)
                    phase = np.where(np.isnan(bh.speckle_phase_rad), plain, bh.speckle_phase_rad)
                hits = HitBatch(seg=np.asarray(beam_seg[emitting])[bh.beam].astype(np.intp),
                                tau_s=bh.tau_s, amplitude_v=bh.amplitude_v * gain * (HYBRID_CHANNEL_AMPLITUDE if iq else 1.0),
                                doppler_hz=-2.0 * bh.velocity_mps / self.cfg.chirp.wavelength_m,
                                phase_rad=phase)
        noise_asd = gain * self.world.white_noise_asd_v() if (eff.noise and light) else 0.0
        if eff.quantization:
            noise_asd = float(np.hypot(noise_asd, self._core_asd(cfg)))
        mzi_asd = self._monitor_asd(cfg) if light else 0.0
        linewidth = self.laser.linewidth_hz if (eff.phase_noise and light) else 0.0
        want_mzi = "mzi" in cfg.channels and light
        # the quadrature output exists only with the hybrid fitted ([monitor] quadrature); without
        # it the mzi_q input is unconnected and reads 0
        want_q = want_mzi and "mzi_q" in cfg.channels and self.cfg.monitor.quadrature
        linewidth = self._phase_noise_linewidth(linewidth, hits, want_mzi, noise_asd)
        if hits is not None:
            self.fidelity.note("doppler", bool(np.any(hits.doppler_hz != 0)))
            self.fidelity.note("speckle", hits.phase_rad is not None)
            self.fidelity.note("mixed_pixels", bh.mixed_beams > 0)   # hits come from bh
        rng = np.random.default_rng([self.seed, self._run_index(), int(first)])
        a = self.cfg.adc
        aa = decimation_filter(cfg.sample_rate_hz, a.max_sample_rate_hz, a.stopband_db)
        syn = synthesize(self._trajectory(), adc, np.zeros(n), hits, noise_asd_v_per_rthz=noise_asd, beat_filter=aa,
                         linewidth_hz=linewidth, rng=rng,
                         mzi_delay_s=self._truth.mzi_delay_s if want_mzi else None,
                         mzi_amplitude_v=self.cfg.monitor.amplitude_v if want_mzi else None,
                         mzi_noise_asd_v_per_rthz=mzi_asd if want_mzi else 0.0, mzi_quadrature=want_q,
                         iq_imbalance=(self._truth.iq_gain, self._truth.iq_phase_rad))
        by_name = {"beat": syn.beat, "beat_i": syn.beat, "beat_q": syn.beat_q, "mzi": syn.mzi, "mzi_q": syn.mzi_q}
        # a scan's one beat channel: the synthesized records are the batch's codes, no copy
        single = tuple(cfg.channels) in (("beat",), ("beat_i",))
        codes = syn.beat[:, None, :] if single else np.zeros((n, len(cfg.channels), cfg.record_length), np.int16)
        over = np.zeros((n, len(cfg.channels)), dtype=bool)
        for j, name in enumerate(cfg.channels):
            data = by_name.get(name)
            if data is not None:
                if not single:
                    codes[:, j] = data
                if name in syn.channels:
                    over[:, j] = syn.overrange[:, syn.channels.index(name)]
                if name in ("beat", "beat_i", "beat_q") and hits is not None:
                    over[:, j] |= core_overrange(hits, n, cfg.input_range_v)
                if name in ("mzi", "mzi_q") and not lit.all():
                    codes[~lit, j] = 0  # no light, no MZI fringes
        if "tap" in cfg.channels and n:
            j = cfg.channels.index("tap")
            power = np.zeros(n)
            if switches:
                np.add.at(power, beam_seg, np.where(lit[beam_seg], trans, 0.0))
            codes[:, j], over[:, j] = self._tap_codes(power, adc, first)
        self.segments_synthesized += n
        return CapturedSegments(trigger_time_s=np.asarray(trig.t_s, dtype=np.float64), codes=codes,
                                overrange=over)


#: a 90-degree hybrid splits the LO and the return four ways: each balanced pair (I or Q) carries
#: R sqrt(P_LO P_rx) of AC current against 2 R sqrt(P_LO P_rx) for the single photodiode of the §4.4
#: circulator set-up, i.e. half the amplitude per channel; each channel keeps the single photodiode's
#: noise (its own TIA and converter) -- docs/physics.md, "The coherent (I/Q) receiver"
HYBRID_CHANNEL_AMPLITUDE = 0.5


def core_overrange(hits: HitBatch, n_seg: int, input_range_v: float) -> np.ndarray:
    """Segments whose returns, BEFORE the decimation filter, exceed the core's full scale (+-range/2):
    a strong return beyond the gate clips the converter even though the filter hides it from the
    record, and the digitizer flags the segment (what bounds a leak: lidard.physics.decimation)."""
    peak = np.bincount(np.asarray(hits.seg, np.intp), weights=np.abs(hits.amplitude_v), minlength=n_seg)
    return peak > 0.5 * input_range_v


class _ControlServer:
    """JSON-lines control socket on 127.0.0.1 for a bench running as its own process.

    Every reply is ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``. Fault commands:
    ``{"cmd": "inject", "kind": K, **params}`` -> ``{"fault": {...}}``,
    ``{"cmd": "clear_faults", "kind": K | null}`` -> ``{"cleared": n}``,
    ``{"cmd": "faults"}`` -> ``{"faults": [...]}``. Tests and benchmarks only:
    ``{"cmd": "truth"}`` -> ``{"truth": BenchTruth.as_dict()}`` (the hidden tolerances).
    """

    def __init__(self, bench: Bench) -> None:
        self.bench = bench
        self._sock = socket.create_server(("127.0.0.1", 0))
        self.port = self._sock.getsockname()[1]
        self._closed = False
        self._thread = threading.Thread(target=self._serve, name="bench-control", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._closed:
            try:
                conn, _ = self._sock.accept()
            except OSError:
                return
            threading.Thread(target=self._client, args=(conn,), daemon=True).start()

    def _client(self, conn: socket.socket) -> None:
        with conn, conn.makefile("rwb") as f:
            for line in f:
                try:
                    reply = {"ok": True, **self.handle(json.loads(line))}
                except (SceneError, ValueError, KeyError, TypeError) as exc:
                    reply = {"ok": False, "error": str(exc)}
                f.write((json.dumps(reply) + "\n").encode())
                f.flush()

    def handle(self, msg: dict) -> dict:
        b = self.bench
        cmd = msg.get("cmd")
        if cmd == "ping":
            return {"t_s": b.clock.now()}
        if cmd == "advance":
            return {"t_s": b.clock.advance(float(msg["dt_s"]))}
        if cmd == "set_scene":
            scene = Scene.from_dict(msg["scene"], source="<control>")
            b.set_scene(scene)
            return {"name": scene.name, "targets": len(scene)}
        if cmd == "set_interlock":
            b.controller.set_interlock(bool(msg["closed"]))
            return {}
        if cmd == "inject":
            params = {k: v for k, v in msg.items() if k not in ("cmd", "kind")}
            return {"fault": b.inject_fault(msg.get("kind"), **params)}
        if cmd == "clear_faults":
            return {"cleared": b.clear_faults(msg.get("kind"))}
        if cmd == "faults":
            return {"faults": b.active_faults()}
        if cmd == "fidelity":
            return {"fidelity": b.fidelity.snapshot()}
        if cmd == "truth":   # the hidden tolerances, for tests/benchmarks of a child bench
            return {"truth": b.truth().as_dict()}
        if cmd == "ground_truth":
            truth = b.ground_truth(np.asarray(msg["rows"]), np.asarray(msg["cols"]))
            return {"range_m": [None if not np.isfinite(x) else float(x) for x in truth]}
        raise ValueError(f"unknown control command {cmd!r}")

    def close(self) -> None:
        self._closed = True
        self._sock.close()


class BenchControlClient:
    """Client of a child bench's control socket (used by the composition root of lidard)."""

    def __init__(self, port: int, host: str = "127.0.0.1") -> None:
        self._sock = socket.create_connection((host, port), timeout=10)
        self._f = self._sock.makefile("rwb")
        self._lock = threading.Lock()

    def call(self, cmd: str, **kw) -> dict:
        with self._lock:
            self._f.write((json.dumps({"cmd": cmd, **kw}) + "\n").encode())
            self._f.flush()
            line = self._f.readline()
        if not line:
            raise ConnectionError("simulated bench closed its control socket")
        reply = json.loads(line)
        if not reply.pop("ok"):
            raise ValueError(reply.get("error", "bench control error"))
        return reply

    def close(self) -> None:
        self._f.close()
        self._sock.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="lidar-sim", description="Run the simulated LiDAR bench.")
    ap.add_argument("--config", default=None, help="lidard configuration (TOML); default config/sim.toml")
    ap.add_argument("--scene", default=None, help="scene file (TOML); default: the config's sim.scene")
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--json", action="store_true", help="print the endpoints as one JSON line")
    args = ap.parse_args(argv)
    try:
        cfg = load_config(args.config or Path(__file__).resolve().parent.parent / "config" / "sim.toml")
        scene = Scene.from_toml(args.scene) if args.scene else None
        bench = Bench(cfg, scene, seed=args.seed)
    except (ConfigError, SceneError) as exc:
        print(f"lidar-sim: {exc}", file=sys.stderr)
        return 2
    ep = bench.start(usb="tcp", control=True)
    if args.json:
        print(json.dumps(ep), flush=True)
    else:
        for k, v in ep.items():
            print(f"{k}: {v}", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())

    def watch_stdin():
        # A parent that dies (even by SIGKILL) closes our stdin: leave with it.
        try:
            while sys.stdin.buffer.read(1):
                pass
        except (OSError, ValueError):
            pass
        stop.set()

    if not sys.stdin.isatty():
        threading.Thread(target=watch_stdin, daemon=True).start()
    stop.wait()
    bench.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
