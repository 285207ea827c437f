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

Hidden truths (:mod:`sim_devices.world.tolerances`): the bench draws, from
``[sim.tolerances]`` and its seed, the monitor MZI's true delay (used for the monitor fringes
instead of the configured ``monitor.delay_s``), the range zero offset and the true pointing (both
in the world). ``Bench.truth()`` and the control command ``truth`` give them to tests and
benchmarks; the daemon has only the nominal configuration.

The FPGA's serial port is published as a STABLE path, a symlink in the bench's temp dir (like
``/dev/serial/by-id/...``) that points at the current pty slave: after a ``serial_disconnect`` fault
is cleared the FPGA comes back on a NEW pty and the symlink is re-pointed, so a driver reopens the
same ``fpsa_url``.

Fault injection: ``inject_fault(kind, **params) -> dict``, ``clear_faults(kind=None) -> int``,
``active_faults()`` (the bench's :class:`~sim_devices.bench.fault_injector.FaultInjector`,
``bench.faults``); ``[[sim.faults]]`` tables of the configuration are injected by :meth:`Bench.start`. Tap channel (self-test): digitizer channel ``tap`` is a monitor photodiode on
the light leaving the FPSA (one beam for a healthy pixel, two when a line is stuck on, none when
one is stuck off).

Parts: this module builds the bench and runs it (devices, lifecycle, the FPGA's pty behind a stable
path, world control, ``lidar-sim``). The bench HOLDS its parts, each given the devices it acts on: the
fault injector (``bench.faults``, ``sim_devices.bench.fault_injector``), the segment synthesizer (the
digitizer's ``SegmentSource`` and the tap channel: ``bench.synthesizer``, ``sim_devices.bench.capture``)
and the JSON control socket and its client (``sim_devices.bench.control``).

This module is a composition root of the simulator; like the world it reads ``lidard.config``.
"""

from __future__ import annotations

import argparse
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

from lidard import heap
from lidard.config import Config, ConfigError, load_config
from sim_devices.awg.device import SimAwg
from sim_devices.bench.capture import (
    HYBRID_CHANNEL_AMPLITUDE,
    CaptureDevices,
    LaserParts,
    SegmentSynthesizer,
    TapSpec,
    core_overrange,
)
from sim_devices.bench.control import BenchControlClient, _ControlServer
from sim_devices.bench.fault_injector import FaultInjector, FaultTargets
from sim_devices.clock import VirtualClock
from sim_devices.controller.device import ControllerSim
from sim_devices.digitizer.device import CaptureConfig, CapturedSegments, SimDigitizer
from sim_devices.faults import SerialLineNoise, validate_fault
from sim_devices.fpsa.device import FpgaConfig, FpgaSim
from sim_devices.fpsa.hv_drive import HvDrive
from sim_devices.fpsa.serial_port import PtyServer
from sim_devices.usb.backend import SimUsbBackend, UsbBridgeServer
from sim_devices.world.fidelity import FidelityLedger
from sim_devices.world.laser import DfbLaser
from sim_devices.world.mems import SwitchDynamics
from sim_devices.world.scene import Scene, SceneError
from sim_devices.world.tec import from_tolerances as tec_model
from sim_devices.world.tolerances import BenchTruth, draw_truth
from sim_devices.world import synth_jit
from sim_devices.world.world import World


class FpsaPort:
    """The FPGA's serial port behind a STABLE path (a symlink to the current pty slave, like
    ``/dev/serial/by-id/...``): dropped by a ``serial_disconnect`` fault, opened again on a new pty."""

    def __init__(self, fpga: FpgaSim, serial_line: SerialLineNoise) -> None:
        self.fpga = fpga
        self.serial_line = serial_line
        self.path: str | None = None    # set when the bench starts
        self._pty: PtyServer | None = None

    @property
    def is_open(self) -> bool:
        return self._pty is not None

    @property
    def published(self) -> bool:
        """True once the bench has given the port its stable path."""
        return self.path is not None

    def open(self) -> None:
        self._pty = self.fpga.serve_pty(self.serial_line)
        assert self.path is not None
        tmp = self.path + ".new"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(self._pty.path, tmp)
        os.replace(tmp, self.path)  # atomic: a reader sees the old or the new target

    def drop(self) -> None:
        self.close()
        if self.path is not None and os.path.lexists(self.path):
            os.unlink(self.path)  # the device node vanishes, as /dev/serial/by-id/* does
        self.fpga.reset_link()

    def close(self) -> None:
        if self._pty is not None:
            self._pty.close()
            self._pty = None


class Bench:
    """Every simulated device around one world and one virtual clock.

    Holds its fault injector (``faults``: :class:`~sim_devices.bench.fault_injector.FaultInjector`)
    and its segment synthesizer (``synthesizer``: :class:`~sim_devices.bench.capture.SegmentSynthesizer`,
    the digitizer's segment source)."""

    def __init__(self, cfg: Config, scene: Scene | None = None, *, seed: int | None = None) -> None:
        self.cfg = cfg
        for i, entry in enumerate(cfg.sim.faults):   # fail before anything starts, naming the entry
            params = {k: v for k, v in entry.items() if k != "kind"}
            try:
                validate_fault(entry.get("kind"), params)
            except ValueError as exc:
                raise ConfigError(f"{cfg.source}: sim.faults: entry {i}: {exc}") from None
        self.profile = cfg.resolved.profile
        self.laser_preset = cfg.resolved.laser
        if scene is None:
            scene = Scene.from_toml(cfg.resolve_path(cfg.sim.scene))
        self.seed = cfg.sim.seed if seed is None else int(seed)
        self.clock = VirtualClock()
        # the hidden truths: drawn once, never told to the daemon
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
        self.digitizer = SimDigitizer(self.clock, source=self)   # Bench.capture: the synthesizer's segments
        # the laser's true temperature moves its chirp (sim_devices.world.tec)
        self.tec_tuning, tec_drift = tec_model(cfg.sim.tolerances, self.seed)
        self.controller = ControllerSim(self.clock, tec_drift=tec_drift)
        self.fpga.supply = self._hv_drive  # the controller's HV is the HV583 supply rail
        self._bridge: UsbBridgeServer | None = None
        self._control: _ControlServer | None = None
        self.usb_backend: SimUsbBackend | None = None
        # Serial line noise seeded from the bench seed: a run with faults repeats byte for byte.
        self.serial_line = SerialLineNoise((self.seed, 0x5E71A1))
        self.fpsa_port = FpsaPort(self.fpga, self.serial_line)
        self._tmpdir: str | None = None
        self.faults = FaultInjector(FaultTargets(
            clock=self.clock, fpga=self.fpga, awg=self.awg, digitizer=self.digitizer, controller=self.controller,
            serial_line=self.serial_line, port=self.fpsa_port, rows=pr.rows, cols=pr.cols,
            segments_synthesized=lambda: self.synthesizer.segments_synthesized))
        self.synthesizer = SegmentSynthesizer(
            cfg, self.world, LaserParts(self.laser, self.laser_preset, self.tec_tuning),
            CaptureDevices(self.fpga, self.awg, self.controller), self.faults, seed=self.seed, truth=self._truth)

    @property
    def fpsa_link(self) -> str | None:
        """The FPGA's serial port: a stable path (None before :meth:`start`)."""
        return self.fpsa_port.path

    @property
    def fidelity(self) -> FidelityLedger:
        return self.synthesizer.fidelity

    @property
    def tap(self) -> TapSpec:
        return self.synthesizer.tap

    @property
    def segments_synthesized(self) -> int:
        return self.synthesizer.segments_synthesized

    # -- faults and capture: the held parts -----------------------------------------------------------
    def inject_fault(self, kind: str, **params: Any) -> dict[str, Any]:
        """Inject a fault (catalogue: ``sim_devices.faults``); see :meth:`FaultInjector.inject`."""
        return self.faults.inject(kind, **params)

    def clear_faults(self, kind: str | None = None) -> int:
        """Clear active faults of ``kind`` (all if None); returns how many were cleared."""
        return self.faults.clear(kind)

    def active_faults(self) -> list[dict[str, Any]]:
        return self.faults.active()

    def capture(self, first: int, count: int, cfg: CaptureConfig) -> CapturedSegments:
        """Segments ``first`` .. ``first + count - 1`` as the digitizer would stream them."""
        return self.synthesizer.capture(first, count, cfg)

    def tap_volts_per_beam(self) -> float:
        """Tap level of one fully open beam (what a healthy pixel reads), V."""
        return self.synthesizer.tap_volts_per_beam()

    # -- lifecycle ----------------------------------------------------------------------------------
    def start(self, *, usb: str = "inproc", control: bool = False) -> dict[str, Any]:
        """Serve the FPGA on a pty, the controller on Modbus TCP and the USB devices; apply the
        configuration's ``[[sim.faults]]``; return endpoints."""
        self._tmpdir = tempfile.mkdtemp(prefix="lidard-bench-")
        self.fpsa_port.path = os.path.join(self._tmpdir, "fpsa")
        self.fpsa_port.open()
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
        self.faults.close()
        for thing in (self._control, self._bridge, self.fpsa_port):
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

    def _hv_drive(self) -> HvDrive:
        st = self.controller.state
        return HvDrive(st.hv_v if st.hv_on else 0.0, st.hv_hold_setpoint_v if st.hv_on else 0.0)

    # -- world control ------------------------------------------------------------------------------
    def set_scene(self, scene: Scene) -> None:
        with self.synthesizer.lock:
            self.world.set_scene(scene)

    def ground_truth(self, rows, cols, t_s=None, measured_m=None) -> np.ndarray:
        """First-hit range per pixel; ``t_s``: scene time per pixel (a point's ``t``) for moving targets;
        ``measured_m``: score mixed pixels against their footprint's nearest return (World.ground_truth)."""
        with self.synthesizer.lock:
            return self.world.ground_truth(rows, cols, t_s, measured_m)

    def mixed_pixels(self, rows, cols) -> np.ndarray:
        """True per pixel where the footprint crosses a target outline (weighted returns)."""
        with self.synthesizer.lock:
            return self.world.is_mixed(rows, cols)

    def hold_scene_clock(self, hold: bool) -> None:
        """Scene time counts from the first trigger of the next run while held (see
        :meth:`SegmentSynthesizer.hold_scene_clock`)."""
        self.synthesizer.hold_scene_clock(hold)

    @staticmethod
    def start_kernel_load() -> bool:
        """Load the compiled synthesis kernels on a thread of their own now (once per process), for a
        bench that will serve scans nobody has announced (sim_devices.world.synth_jit.start_load); a
        read that needs them meanwhile waits for them. Answers whether a load started."""
        return synth_jit.start_load()

    @staticmethod
    def wait_kernels() -> None:
        """Wait for a load :meth:`start_kernel_load` or :meth:`expect_scan` started, if any."""
        synth_jit.wait_loaded()

    def expect_scan(self, samples: int) -> bool:
        """A scan of ``samples`` record samples is coming (a one-shot command, before the scan's ARM):
        the synthesis loads the compiled kernels it will need now, beside the command's set-up, when the
        scan alone pays for them (sim_devices.world.synth_jit.load_ahead). Answers whether a load started."""
        return synth_jit.load_ahead(samples)

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
    # Before any thread exists: a bench process serves a daemon for as long as it runs, and every read
    # allocates and frees 0.5-16 MB arrays on the synthesis pool's threads (lidard.heap). Every array
    # numpy advises huge pages on is a mapping of its own; the smaller ones are reused from the heaps
    # from read to read (no page faults: a 256 KiB threshold made them fresh mappings, ~0.1 s of system
    # time a small scan), whose free pages go back once the bench has gone idle (below).
    heap.configure(mmap_threshold=heap.NUMPY_HUGEPAGE_BYTES, trim_threshold=heap.HEAP_BYTES)
    # A bench process serves a daemon for as long as it runs: load the compiled synthesis kernels now,
    # rather than when its scans pass their break-even minutes later (a ~130 MB jump of its memory at a
    # time that depends on the scans; sim_devices.world.synth_jit.load_now). The load runs beside the
    # bench's construction, and the bench serves only once it is done: numba's import and code
    # generator hold the interpreter for seconds on a busy machine, and a controller read that waits
    # behind them past the driver's timeouts (3 x 0.5 s) failed a daemon's first self-test or scan.
    Bench.start_kernel_load()
    try:
        cfg = load_config(args.config or Path(__file__).resolve().parent.parent / "config" / "sim.toml")
        scene = Scene.from_toml(args.scene) if args.scene else None
        bench = Bench(cfg, scene, seed=args.seed)
    except (ConfigError, SceneError) as exc:
        print(f"lidar-sim: {exc}", file=sys.stderr)
        return 2
    Bench.wait_kernels()
    stop = threading.Event()
    trimmer = heap.IdleTrimmer(lambda: bench.synthesizer.segments_synthesized, heap.BENCH_IDLE_S)
    threading.Thread(target=trimmer.run, args=(stop,), name="lidar-sim-heap-trim", daemon=True).start()
    ep = bench.start(usb="tcp", control=True)
    if args.json:
        print(json.dumps(ep), flush=True)
    else:
        for k, v in ep.items():
            print(f"{k}: {v}", flush=True)
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
