"""The composition root: a configuration becomes running drivers and a :class:`LidarInstrument`.

For a simulated configuration the simulated bench (sim_devices) is started first, embedded in this
process or as a ``lidar-sim`` child process, and the device addresses are taken from it; the
instrument then talks to it over the same bytes as to the lab bench of dissertation §4.4.1 (serial
to the FPGA, USB to the AWG and digitizer, Modbus TCP to the laser/HV controller). This is the only
module of lidard that imports sim_devices (an import-linter contract in pyproject.toml).
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
from typing import Any

from drivers.awg.driver import AwgDriver
from drivers.controller.driver import LaserHvController
from drivers.controller.protocol import Limits
from drivers.digitizer.driver import DigitizerDriver
from drivers.fpsa.driver import FpsaController, FpsaLink

from ..config import Config
from .devices import DeviceRegistry
from .errors import InstrumentError, SceneRejected, SimFaultError
from .facade import LidarInstrument, SimHooks
from .types import ScanRequest

log = logging.getLogger(__name__)


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


def _usb_device(backend, ids: tuple[int, int], who: str):
    dev = _usb_finder(backend, ids)()
    if dev is None:
        raise InstrumentError(f"{who}: no USB device {ids[0]:04x}:{ids[1]:04x} found")
    return dev


def _ms(seconds: float) -> int:
    """A USB transfer timeout in whole milliseconds (pyusb's unit), at least 1 (0 would mean "forever")."""
    return max(1, int(round(seconds * 1000.0)))


def _connect(cfg: Config, endpoints: dict[str, Any] | None, usb_backend, sleep) -> DeviceRegistry:
    """The four drivers (addresses "bench" are taken from ``endpoints``)."""
    from drivers.awg import protocol as awg_p
    from drivers.digitizer import protocol as dig_p

    d = cfg.devices
    ep = endpoints or {}
    on_bench = endpoints is not None and d.controller.host == "bench"
    fpsa_url = ep["fpsa_url"] if endpoints and d.fpsa.url == "bench" else d.fpsa.url
    host = ep["controller_host"] if on_bench else d.controller.host
    port = ep["controller_port"] if on_bench else d.controller.port
    # Backoffs go through ``sleep`` (the virtual clock on a bench) so a device that comes back after
    # some virtual time is found again without any wall-clock wait.
    fpsa = FpsaController.from_url(fpsa_url, baudrate=d.fpsa.baudrate, link=FpsaLink(timeout_s=d.fpsa.timeout_s, sleep=sleep))
    ctrl = LaserHvController(host, port, device_id=d.controller.device_id, timeout_s=d.controller.timeout_s,
                             # the laser preset's absolute maximum caps the controller's limit too
                             limits=Limits(max_laser_current_ma=min(d.controller.max_laser_current_ma,
                                                                    cfg.resolved.laser.max_current_ma),
                                           max_hv_v=d.controller.max_hv_v, tec_range_c=(15.0, 40.0)),
                             sleep=sleep, busy_retries=3)
    awg_ids = _usb_ids(d.awg.usb, (awg_p.AWG_VID, awg_p.AWG_PID), "awg")
    dig_ids = _usb_ids(d.digitizer.usb, (dig_p.DIGITIZER_VID, dig_p.DIGITIZER_PID), "digitizer")
    awg = AwgDriver(_usb_device(usb_backend, awg_ids, "awg"), finder=_usb_finder(usb_backend, awg_ids),
                    timeout_ms=_ms(d.awg.timeout_s), sleep=sleep)
    dig = DigitizerDriver(_usb_device(usb_backend, dig_ids, "digitizer"), finder=_usb_finder(usb_backend, dig_ids),
                          timeout_ms=_ms(d.digitizer.timeout_s), sleep=sleep)
    return DeviceRegistry(fpsa=fpsa, awg=awg, digitizer=dig, controller=ctrl)


def open_instrument(cfg: Config, *, scene_path: str | None = None, bench: str | None = None,
                    expect: ScanRequest | None = None, preload: bool = True) -> LidarInstrument:
    """Build the instrument a configuration describes.

    Simulated configurations start the bench first: ``bench="embedded"`` runs it in this process
    (the default of ``lidarctl scan --sim``), ``"child"`` as a ``lidar-sim`` child process that talks
    over a real pty, Modbus TCP and the USB socket bridge (the daemon's default, ``sim.bench``).

    ``expect``: the one scan the instrument is opened for (a one-shot command). What that scan needs
    starts as soon as the instrument is open and runs beside the caller's set-up
    (:meth:`LidarInstrument.expect_scan`). Without it, a simulated bench will serve scans nobody has
    announced, so it is ready only once its compiled synthesis kernels are loaded (an embedded bench
    here; a ``lidar-sim`` process at its start): that one-off load (~0.4 s, numba and its code
    generator) belongs to the simulated instrument's start, never to its first scan, which real
    hardware would not pay either. ``preload=False``: a one-shot command that runs no scan of its own
    (a self-test) leaves the load to the synthesis's break-even.
    """
    if not cfg.sim.enabled:
        if scene_path is not None:
            raise InstrumentError("--scene needs a simulated configuration (sim.enabled = true)")
        from usb.backend import libusb1

        inst = LidarInstrument(cfg, _connect(cfg, None, libusb1.get_backend(), time.sleep), simulated=False)
    else:
        mode = bench or cfg.sim.bench
        if mode == "embedded":
            inst = _open_embedded(cfg, scene_path, load_kernels=expect is None and preload)
        elif mode == "child":
            inst = _open_child(cfg, scene_path)
        else:
            raise InstrumentError(f"sim.bench must be 'embedded' or 'child', got {mode!r}")
    if expect is not None:
        try:
            inst.expect_scan(expect)
        except BaseException:
            inst.close()
            raise
    return inst


def _open_embedded(cfg: Config, scene_path: str | None, *, bench_cfg: Config | None = None,
                   scene: dict | None = None, load_kernels: bool = True) -> LidarInstrument:
    """``load_kernels``: the bench's compiled synthesis kernels load beside its construction and the
    instrument is returned once they are loaded (open_instrument)."""
    from sim_devices.bench.bench import Bench
    from sim_devices.world.scene import Scene, SceneError

    if load_kernels:
        Bench.start_kernel_load()

    start_scene: Scene | None
    if scene is not None:
        start_scene = Scene.from_dict(scene, source="<scene>")
    else:
        start_scene = Scene.from_toml(scene_path) if scene_path else None
    b = Bench(bench_cfg or cfg, start_scene)
    if load_kernels:
        # loaded before the bench serves, as a lidar-sim process is: numba's load holds the interpreter,
        # and the drivers' first reads behind it would run into their timeouts on a busy machine
        Bench.wait_kernels()
    ep = b.start(usb="inproc")
    drivers = _connect(cfg, ep, b.usb_backend, b.clock.advance)

    def set_scene(d: dict) -> dict:
        try:
            scene = Scene.from_dict(d, source="<request>")
        except SceneError as exc:
            raise SceneRejected(str(exc)) from None
        b.set_scene(scene)
        return {"name": scene.name, "targets": len(scene)}

    hooks = SimHooks(set_scene=set_scene,
                     inject_fault=lambda kind, **params: b.inject_fault(kind, **params),
                     clear_faults=b.clear_faults,
                     active_faults=lambda: b.active_faults(),
                     fidelity=b.fidelity.snapshot, hold_scene_clock=b.hold_scene_clock, expect_scan=b.expect_scan)
    # on_close is the bench's own close: tests reach the embedded bench as ``inst._on_close.__self__``
    return LidarInstrument(cfg, drivers, simulated=True, sleep=b.clock.advance, now=b.clock.now, sim=hooks,
                           on_close=b.close)


def open_split_bench(daemon_cfg: Config, bench_cfg: Config, scene: dict | None = None) -> LidarInstrument:
    """An embedded bench built from ``bench_cfg`` driven by the instrument of ``daemon_cfg`` (tests and
    benchmarks: a known deviation between the daemon's nominal values and the bench's truth, e.g. its
    monitor MZI at 201 ns while the daemon says 200 ns). ``scene``: the scene file's structure (default:
    an empty scene)."""
    return _open_embedded(daemon_cfg, None, bench_cfg=bench_cfg, scene=scene if scene is not None else {"target": []})


def _start_child(cfg: Config, scene_path: str | None) -> tuple[subprocess.Popen, dict[str, Any]]:
    """Start ``lidar-sim --json`` on the same configuration file; answers the process and its endpoints."""
    cmd = [sys.executable, "-m", "sim_devices.bench.bench", "--json"]
    if cfg.path is not None:
        cmd += ["--config", str(cfg.path)]
    if scene_path:
        cmd += ["--scene", str(scene_path)]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=os.environ.copy())
    stderr_tail: collections.deque[str] = collections.deque(maxlen=20)

    assert proc.stdin is not None and proc.stdout is not None and proc.stderr is not None   # all PIPE
    stdout, stderr = proc.stdout, proc.stderr

    def forward_stderr() -> None:   # the child's complaints go to our log, the last ones into errors
        for raw in stderr:
            text = raw.decode("utf-8", "replace").rstrip()
            stderr_tail.append(text)
            log.warning("%s", text if text.startswith("lidar-sim") else f"lidar-sim: {text}")

    reader = threading.Thread(target=forward_stderr, name="lidar-sim-stderr", daemon=True)
    reader.start()
    line = stdout.readline()
    if not line:
        proc.kill()
        reader.join(timeout=5)
        why = stderr_tail[-1] if stderr_tail else "no message"
        raise InstrumentError(f"simulated bench: the lidar-sim child process did not start: {why}")
    return proc, json.loads(line)


def _open_child(cfg: Config, scene_path: str | None) -> LidarInstrument:
    from sim_devices.bench.bench import BenchControlClient
    from sim_devices.usb.backend import backend_from_url

    proc, ep = _start_child(cfg, scene_path)
    ctl = BenchControlClient(ep["control_port"])

    def advance(dt_s: float) -> None:
        ctl.call("advance", dt_s=float(dt_s))

    def stop_child() -> None:
        ctl.close()
        try:
            if proc.stdin is not None:
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

    def clear_faults(kind: str | None = None) -> int:
        return int(call("clear_faults", kind=kind)["cleared"])

    hooks = SimHooks(set_scene=set_scene,
                     inject_fault=lambda kind, **params: call("inject", kind=kind, **params)["fault"],
                     clear_faults=clear_faults,
                     active_faults=lambda: call("faults")["faults"],
                     fidelity=lambda: call("fidelity")["fidelity"],
                     hold_scene_clock=lambda hold: call("hold_scene_clock", hold=bool(hold)))
    drivers = _connect(cfg, ep, backend_from_url(ep["usb_url"]), advance)
    return LidarInstrument(cfg, drivers, simulated=True, sleep=advance, now=lambda: float(ctl.call("ping")["t_s"]),
                           sim=hooks, on_close=stop_child)
