"""The simulated bench: one world, one virtual clock, every simulated instrument (`lidar-sim`).

Wires the byte-level peers to one :class:`~sim_devices.world.world.World` (scene, optics, link
budget), one DFB laser model and one :class:`~sim_devices.clock.VirtualClock`:

* the FPGA (``sim_devices.fpga``, served on a pty) steps the uploaded pattern and decides, per
  trigger, which pixel is commanded and which beams actually leave the chip (MEMS dynamics, §4.3.6);
* the AWG (USBTMC over the pyusb backend) holds the drive waveform that the laser model turns into
  nu(t) (the trajectory is computed once per waveform and cached);
* the controller (Modbus TCP) gates the light: no laser output unless the laser is on and the
  interlock closed, no switch actuation unless the HV output is above the switches' pull-in voltage;
* the digitizer (vendor bulk protocol over the pyusb backend) asks this bench, as its
  ``SegmentSource``, for the segments it streams: triggers from the FPGA, beams -> hits -> beat
  tones from the world, synthesized at the sample rate the host configured (never a fixed high rate).
  A record format wider than the ADC core (16-bit records from the 8-bit core of Table 2-2) models
  on-board decimation from the core's full rate: the core's quantization noise is added as white
  noise over its full Nyquist band, then the record is quantized at the format's resolution.

Each trigger starts one period (up + down ramp) of the AWG waveform, so every segment's record starts
at t = 0 of the drive period. Segment noise is seeded from (bench seed, run, first segment index), so a
re-read of the same batch gives the same bytes.

Modes: in-process (``Bench(...).start(usb="inproc")``, the embedded default of ``lidarctl scan --sim``)
or as its own process (``lidar-sim --json``: prints its endpoints as one JSON line and serves until
stdin closes or it gets SIGTERM), with the USB transfers carried over a local socket and a small JSON
control socket (set_scene, set_interlock, advance, ground_truth, ping).

This module is a composition root of the simulator; like the world it reads ``lidard.config``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import signal
import socket
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np

from lidard.config import Config, ConfigError, load_config
from lidard.physics.budget import quantization_asd

from .awg import SimAwg
from .clock import VirtualClock
from .controller import ControllerSim
from .digitizer import CaptureConfig, CapturedSegments, SimDigitizer
from .fpga import FpgaConfig, FpgaSim
from .usb_backend import SimUsbBackend, UsbBridgeServer
from .world.laser import DfbLaser
from .world.mems import SwitchDynamics
from .world.scene import Scene, SceneError
from .world.synth import AdcSpec, HitBatch, synthesize, trajectory
from .world.world import World


class Bench:
    """Every simulated device around one world and one virtual clock."""

    def __init__(self, cfg: Config, scene: Scene | None = None, *, seed: int | None = None) -> None:
        self.cfg = cfg
        self.profile = cfg.load_profile()
        self.laser_preset = cfg.load_laser()
        if scene is None:
            scene = Scene.from_toml(cfg.resolve_path(cfg.sim.scene))
        self.seed = cfg.sim.seed if seed is None else int(seed)
        self.clock = VirtualClock()
        self.world = World(cfg, self.profile, self.laser_preset, scene)
        self.laser = DfbLaser(self.laser_preset)
        pr = self.profile
        row_dyn = SwitchDynamics(pr.row_switch.on_s, pr.row_switch.off_s, pull_in_v=pr.pull_in_v,
                                 release_v=pr.release_v)
        col_dyn = SwitchDynamics(pr.col_switch.on_s, pr.col_switch.off_s, pull_in_v=pr.pull_in_v,
                                 release_v=pr.release_v)
        self.fpga = FpgaSim(self.clock, FpgaConfig(
            rows=pr.rows, cols=pr.cols, bonded_rows=pr.bonded_rows,
            baudrate=cfg.devices.fpsa.baudrate, hv_supply_v=pr.actuation_v, seed=self.seed,
            row_dynamics=row_dyn, col_dynamics=col_dyn))
        self.awg = SimAwg()
        self.digitizer = SimDigitizer(self.clock, source=self)
        self.controller = ControllerSim(self.clock)
        self._traj_key: bytes | None = None
        self._traj = None
        self._lock = threading.RLock()
        self._pty = None
        self._bridge: UsbBridgeServer | None = None
        self._control: _ControlServer | None = None
        self.usb_backend = None
        self.segments_synthesized = 0

    # -- lifecycle ----------------------------------------------------------------------------------
    def start(self, *, usb: str = "inproc", control: bool = False) -> dict[str, Any]:
        """Serve the FPGA on a pty, the controller on Modbus TCP and the USB devices; return endpoints."""
        self._pty = self.fpga.serve_pty()
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
        return self.endpoints(usb_url)

    def endpoints(self, usb_url: str | None = None) -> dict[str, Any]:
        return {
            "fpsa_url": self._pty.path if self._pty else None,
            "controller_host": self.controller.host,
            "controller_port": self.controller.port,
            "usb_url": usb_url or (self._bridge.url if self._bridge else "sim-usb://inproc"),
            "control_port": self._control.port if self._control else None,
        }

    def close(self) -> None:
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

    # -- world control ------------------------------------------------------------------------------
    def set_scene(self, scene: Scene) -> None:
        with self._lock:
            self.world.set_scene(scene)

    def ground_truth(self, rows, cols) -> np.ndarray:
        with self._lock:
            return self.world.ground_truth(rows, cols)

    # -- SegmentSource ------------------------------------------------------------------------------
    def _trajectory(self):
        drive, fs = self.awg.drive_volts()
        if not self.awg.output_on:
            drive = np.zeros_like(drive)
        key = hashlib.sha1(np.ascontiguousarray(drive).tobytes() + repr(float(fs)).encode()).digest()
        if key != self._traj_key:
            self._traj = trajectory(self.laser, drive, fs)
            self._traj_key = key
        return self._traj

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
        switches = bool(st.hv_on and st.hv_v >= self.profile.pull_in_v)
        iq = "beat_i" in cfg.channels
        adc = AdcSpec(sample_rate_hz=cfg.sample_rate_hz, n_samples=cfg.record_length, bits=cfg.bits,
                      input_range_v=cfg.input_range_v, iq=iq, quantize=True)
        hits = None
        if light and switches and n:
            if eff.mems_dynamics:
                rows, cols, trans, beam_seg = (trig.beam_row, trig.beam_col, trig.beam_transmission,
                                               trig.beam_trigger)
            else:
                rows, cols, trans, beam_seg = trig.row, trig.col, np.ones(n), np.arange(n)
            bh = self.world.beam_hits(rows, cols, trans)
            if bh.beam.size:
                hits = HitBatch(seg=np.asarray(beam_seg)[bh.beam].astype(np.intp), tau_s=bh.tau_s,
                                amplitude_v=bh.amplitude_v,
                                doppler_hz=-2.0 * bh.velocity_mps / self.cfg.chirp.wavelength_m)
        noise_asd = self.world.white_noise_asd_v() if (eff.noise and light) else 0.0
        core_bits = self.cfg.adc.bits
        if eff.quantization and cfg.bits > core_bits:
            # A 16-bit record from an 8-bit core: the digitizer samples at its full rate and
            # decimates on board, so the core's quantization noise (LSB^2/12 over the full Nyquist
            # band) lands in the record as white noise; the 16-bit format quantizes the rest.
            q = quantization_asd(self.cfg.adc.input_range_v, core_bits, self.cfg.adc.max_sample_rate_hz)
            noise_asd = float(np.hypot(noise_asd, q))
        linewidth = self.laser.linewidth_hz if (eff.phase_noise and light) else 0.0
        want_mzi = "mzi" in cfg.channels and light
        rng = np.random.default_rng([self.seed, int(self.fpga.run_start_s * 1e9) if self.fpga.run_start_s
                                     else 0, int(first)])
        syn = synthesize(self._trajectory(), adc, np.zeros(n), hits, noise_asd_v_per_rthz=noise_asd,
                         linewidth_hz=linewidth, rng=rng,
                         mzi_delay_s=self.cfg.monitor.delay_s if want_mzi else None,
                         mzi_amplitude_v=self.cfg.monitor.amplitude_v if want_mzi else None)
        codes = np.zeros((n, len(cfg.channels), cfg.record_length), dtype=np.int16)
        over = np.zeros((n, len(cfg.channels)), dtype=bool)
        by_name = {"beat": syn.beat, "beat_i": syn.beat, "beat_q": syn.beat_q, "mzi": syn.mzi}
        for j, name in enumerate(cfg.channels):
            data = by_name.get(name)
            if data is not None:
                codes[:, j] = data
                if name in syn.channels:
                    over[:, j] = syn.overrange[:, syn.channels.index(name)]
        self.segments_synthesized += n
        return CapturedSegments(trigger_time_s=np.asarray(trig.t_s, dtype=np.float64), codes=codes,
                                overrange=over)


class _ControlServer:
    """JSON-lines control socket on 127.0.0.1 for a bench running as its own process."""

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
            b.set_scene(Scene.from_dict(msg["scene"], source="<control>"))
            return {}
        if cmd == "set_interlock":
            b.controller.set_interlock(bool(msg["closed"]))
            return {}
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
