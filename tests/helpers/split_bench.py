"""An embedded bench built from one configuration and the daemon's instrument from another (issue 13).

Until the bench hides its own tolerances (``[sim.tolerances]``), a test makes the daemon's nominal
values differ from the bench's truths this way: e.g. the bench's monitor MZI at 201 ns while the
daemon's configuration says 200 ns. Scenes are set through the instrument's sim hooks, as the daemon
does (``set_scene`` with the scene file's structure).
"""

from __future__ import annotations

from lidard.config import Config
from lidard.instrument.compose import _connect
from lidard.instrument.facade import LidarInstrument, SimHooks
from sim_devices.bench import Bench
from sim_devices.world.scene import Scene


def open_split(daemon_cfg: Config, bench_cfg: Config, scene: dict | None = None) -> LidarInstrument:
    """A started in-process bench of ``bench_cfg`` and the instrument of ``daemon_cfg`` on it."""
    b = Bench(bench_cfg, Scene.from_dict(scene if scene is not None else {"target": []}))
    ep = b.start(usb="inproc")

    def set_scene(d: dict) -> dict:
        s = Scene.from_dict(d, source="<test>")
        b.set_scene(s)
        return {"name": s.name, "targets": len(s)}

    hooks = SimHooks(set_scene=set_scene, inject_fault=b.inject_fault, clear_faults=b.clear_faults,
                     active_faults=b.active_faults)
    return LidarInstrument(daemon_cfg, simulated=True, sleep=b.clock.advance, now=b.clock.now, sim=hooks,
                           on_close=b.close, **_connect(daemon_cfg, ep, b.usb_backend, b.clock.advance))
