"""Benchmark: the cost of mixed pixels (issue 15 item 5), feature on (the default) against off.

Two measurements per scene, each with the scene's ``mixed_pixels`` on and off, interleaved round by
round so the shared machine's noise hits both alike (best of the rounds):

* **cast**: process CPU time of the bench's per-pixel ray cast of a full 128 x 128 frame (``World``
  cache emptied first): central rays, the outline test and the footprint sub-rays; with the rays counted
  (central rays, sub-rays, mixed pixels: deterministic, independent of the machine);
* **scan**: a 16 x 32 ROI scanned end to end by an embedded instrument (capture, synthesis, DSP),
  process CPU time per frame.

Scenes: an infinite wall at 2 m and config/scenes/far_wall.toml (a 120 m wide wall: no outline in
view; "a scene without edges"), config/scenes/cal_letters.toml (§4.4.3: the letters' outlines) and
the static part of config/scenes/mixed.toml.

    python benchmarks/mixed_pixels.py [--rounds 3] [--no-scan]
"""

from __future__ import annotations

import argparse
import platform
import threading

from lidard.dsp_pool import cpu_time  # the DSP worker processes' CPU is a scan's too

import numpy as np

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument import ScanRequest, open_instrument
from sim_devices.world.scene import Scene
from sim_devices.world.world import World

NOMINAL = {"LIDARD__SIM__TOLERANCES__ENABLED": "false"}
ROI = ScanRequest(pattern="roi", rows=(40, 56), cols=(40, 72), max_range_m=3.0)


def scenes() -> dict[str, Scene]:
    wall = Scene.from_dict({"target": [{"kind": "plane", "point": [0, 0, 2.0], "normal": [0, 0, -1],
                                        "reflectivity": 0.2}]})
    mixed = Scene.from_toml(CONFIG_DIR / "scenes" / "mixed.toml").to_dict()
    mixed["target"] = [t for t in mixed["target"] if not any(t.get("velocity", [0, 0, 0]))]
    return {"wall 2 m (infinite)": wall,
            "far_wall.toml": Scene.from_toml(CONFIG_DIR / "scenes" / "far_wall.toml"),
            "cal_letters.toml": Scene.from_toml(CONFIG_DIR / "scenes" / "cal_letters.toml"),
            "mixed.toml (static)": Scene.from_dict(mixed)}


def switched(scene: Scene, on: bool) -> Scene:
    return Scene(scene.targets, scene.name, scene.description, scene.source, on)


def cast_frame(rounds: int) -> dict:
    """Per scene: best-of-rounds cast time of a 128 x 128 frame on / off, and the rays cast."""
    cfg = load_config(CONFIG_DIR / "sim.toml", environ=NOMINAL)
    world = World(cfg, cfg.load_profile(), cfg.load_laser(), Scene())
    rows, cols = np.divmod(np.arange(128 * 128), 128)
    out = {}
    for name, scene in scenes().items():
        t = {True: [], False: []}
        counts = {}
        for _ in range(rounds):
            for on in (False, True):
                world.set_scene(switched(scene, on))
                n0, s0 = world.rays_cast, world.sub_rays_cast
                t0 = cpu_time()
                world._cast_pixels(rows, cols)
                t[on].append(cpu_time() - t0)
                counts[on] = (world.rays_cast - n0, world.sub_rays_cast - s0,
                              int(world.is_mixed(rows, cols).sum()))
        out[name] = {"off_s": min(t[False]), "on_s": min(t[True]), "ratio": min(t[True]) / min(t[False]),
                     "central_rays": counts[True][0], "sub_rays": counts[True][1], "mixed": counts[True][2],
                     "sub_rays_off": counts[False][1]}
    return out


def scan_frame(rounds: int) -> dict:
    """Per scene: best-of-rounds process CPU time of a 16 x 32 ROI scan on / off."""
    inst = open_instrument(load_config(CONFIG_DIR / "sim.toml", environ=NOMINAL),
                           scene_path=str(CONFIG_DIR / "scenes" / "empty.toml"), bench="embedded")
    bench = inst._on_close.__self__
    out = {}
    try:
        cal = inst.linearize()
        inst.run_scan(ROI, lambda p: None, threading.Event(), cal)        # warm-up: DSP tables
        for name, scene in scenes().items():
            cpu = {True: [], False: []}
            for _ in range(rounds):
                for on in (False, True):
                    bench.set_scene(switched(scene, on))                # empties the cast cache
                    c0 = cpu_time()
                    inst.run_scan(ROI, lambda p: None, threading.Event(), cal)
                    cpu[on].append(cpu_time() - c0)
            off, on = min(cpu[False]), min(cpu[True])
            out[name] = {"off_s": off, "on_s": on, "ratio": on / off}
    finally:
        inst.close()
    return out


def machine() -> str:
    model = next((ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name")),
                 platform.processor() or platform.machine()) if platform.system() == "Linux" else platform.machine()
    load = " ".join(f"{x:.1f}" for x in __import__("os").getloadavg())
    return f"{model}, {__import__('os').cpu_count()} cores, load average {load}, python {platform.python_version()}"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--no-scan", action="store_true", help="only the frame cast")
    args = ap.parse_args(argv)
    print(f"machine: {machine()}; best of {args.rounds} interleaved rounds")
    print("128 x 128 frame cast, CPU     off (ms)  on (ms)  ratio  central  sub-rays  mixed px")
    for name, r in cast_frame(args.rounds).items():
        print(f"  {name:26s} {r['off_s'] * 1e3:8.1f} {r['on_s'] * 1e3:8.1f} {r['ratio']:6.2f} "
              f"{r['central_rays']:8d} {r['sub_rays']:9d} {r['mixed']:9d}")
    if not args.no_scan:
        print("16 x 32 ROI scan, CPU s/frame  off      on       ratio")
        for name, r in scan_frame(args.rounds).items():
            print(f"  {name:26s} {r['off_s']:8.3f} {r['on_s']:8.3f} {r['ratio']:6.2f}")


if __name__ == "__main__":
    main()
