"""The simulated bench: one world, one virtual clock, every simulated instrument (`lidar-sim`).

Wires the byte-level peers to one :class:`~sim_devices.world.world.World` (scene, optics, link
budget), one DFB laser model and one :class:`~sim_devices.clock.VirtualClock`:

* the FPGA (``sim_devices.fpsa.device``, served on a pty) steps the uploaded pattern and decides, per
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

Fault injection (issue 6): ``inject_fault(kind, **params) -> dict``, ``clear_faults(kind=None) ->
int``, ``active_faults()``; ``[[sim.faults]]`` tables of the configuration are injected by
:meth:`Bench.start`. Tap channel (self-test): digitizer channel ``tap`` is a monitor photodiode on
the light leaving the FPSA (one beam for a healthy pixel, two when a line is stuck on, none when
one is stuck off).

Parts: this module builds the bench and runs it (devices, lifecycle, the FPGA's pty behind a stable
path, world control, ``lidar-sim``); the fault catalogue's effects are ``sim_devices.bench.fault_injector``,
the segment synthesis (the digitizer's ``SegmentSource``, the tap channel)
``sim_devices.bench.capture``, the JSON control socket and its client ``sim_devices.bench.control``.

This module is a composition root of the simulator; like the world it reads ``lidard.config``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import shutil
import signal
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np

from lidard.config import Config, ConfigError, load_config

from sim_devices.awg.device import SimAwg
from sim_devices.bench.capture import HYBRID_CHANNEL_AMPLITUDE, BenchCapture, TapSpec, core_overrange
from sim_devices.bench.control import BenchControlClient, _ControlServer
from sim_devices.bench.fault_injector import BenchFaults
from sim_devices.clock import VirtualClock
from sim_devices.controller.device import ControllerSim
from sim_devices.digitizer.device import SimDigitizer
from sim_devices.faults import SerialLineNoise, validate_fault
from sim_devices.fpsa.device import FpgaConfig, FpgaSim
from sim_devices.fpsa.hv_drive import HvDrive
from sim_devices.usb.backend import SimUsbBackend, UsbBridgeServer
from sim_devices.world.fidelity import FidelityLedger
from sim_devices.world.laser import DfbLaser
from sim_devices.world.mems import SwitchDynamics
from sim_devices.world.scene import Scene, SceneError
from sim_devices.world.tec import from_tolerances as tec_model
from sim_devices.world.tolerances import BenchTruth, draw_truth
from sim_devices.world.world import World


class Bench(BenchFaults, BenchCapture):
    """Every simulated device around one world and one virtual clock.

    Fault injection: :class:`~sim_devices.bench.fault_injector.BenchFaults`; segment synthesis:
    :class:`~sim_devices.bench.capture.BenchCapture`."""

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
        self._scene_hold, self._scene_epoch_s = False, None   # hold_scene_clock
        self._pty = None
        self._bridge: UsbBridgeServer | None = None
        self._control: _ControlServer | None = None
        self.usb_backend = None
        self.segments_synthesized = 0
        # FPGA run start (virtual s) -> 1, 2, ... in the order runs are first captured: the noise seed
        # (see _run_index)
        self._run_ids: dict[float, int] = {}
        self._runs_captured = 0
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

    def hold_scene_clock(self, hold: bool) -> None:
        """Scene time counts from the first trigger of the next run and runs on across the following
        runs while held (the frames of a stream are one run each; a point's ``t`` counts from the
        stream's first trigger); released, each run starts its scene at t = 0 again."""
        with self._lock:
            self._scene_hold = bool(hold)
            self._scene_epoch_s = None

    def _run_first_trigger_s(self) -> float:
        sched = self.fpga.schedule
        first = 0.0 if sched is None else float(sched.trigger_s(np.array([0]))[0])
        if self._scene_hold:
            if self._scene_epoch_s is None:
                self._scene_epoch_s = first
            return self._scene_epoch_s
        return first

    def truth(self) -> BenchTruth:
        """The bench's hidden true values (sim_devices.world.tolerances): for tests and benchmarks
        only, never for the daemon."""
        return self._truth

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


__all__ = ["Bench", "BenchControlClient", "HYBRID_CHANNEL_AMPLITUDE", "TapSpec", "core_overrange", "main"]


if __name__ == "__main__":
    sys.exit(main())
