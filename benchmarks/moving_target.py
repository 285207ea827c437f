"""Benchmark: targets that move during a scan (issue 14, item 3), through the instrument.

The scene of tests/e2e/test_e2e_motion.py: a 0.5 m box at 4.3 m moving at (1.0, 0, 1.1) m/s (1.49 m/s,
across and along the beams) in front of a wall at 6 m, a 32 x 32 pixel frame (768 bonded pixels),
speed prior 2 m/s, pfa 1e-9. Printed: the frame's hardware time, the range RMS against the ray-cast
truth moved to each point's own t and against the frozen (t = 0) scene, the radial-velocity error,
and the casts: pixels cast once into the static targets, beams cast into the moving one.

Run: python benchmarks/moving_target.py
"""

from __future__ import annotations

import threading

import numpy as np

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument

V_MPS = np.array([1.0, 0.0, 1.1])
SCENE = {"target": [
    {"kind": "box", "center": [-0.25, 0.0, 4.3], "size": [0.5, 0.5, 0.1], "reflectivity": 0.8, "velocity": V_MPS.tolist()},
    {"kind": "plane", "point": [0.0, 0.0, 6.0], "normal": [0.0, 0.0, -1.0], "reflectivity": 0.9}]}


def rms(e: np.ndarray) -> float:
    """RMS in mm."""
    return float(np.sqrt(np.mean(e ** 2))) * 1e3


def main() -> int:
    # scan.pfa is false points per range cell: 1e-17 is the per-ramp level 1e-9 (m ~ 10, lidard.dsp.ranging.points)
    cfg = load_config("config/sim.toml", environ={"LIDARD__SCAN__MAX_SPEED_MPS": "2.0", "LIDARD__SCAN__PFA": "1e-17"})
    inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    bench = inst._on_close.__self__
    try:
        cal = inst.linearize()
        inst.set_scene(SCENE)
        w = bench.world
        n0, m0 = w.rays_cast, w.moving_rays_cast
        res = inst.run_scan(ScanRequest(pattern="roi", rows=(48, 80), cols=(48, 80), max_range_m=7.0),
                            lambda p: None, threading.Event(), cal)
        casts, moving_casts = w.rays_cast - n0, w.moving_rays_cast - m0
        p = res.points[res.points["valid"] == 1]
        moved = bench.ground_truth(p["row"], p["col"], p["t"])
        frozen = bench.ground_truth(p["row"], p["col"])
        box = moved < 5.0
        d = w.optics.directions(p["row"], p["col"])
        print(f"frame: {res.pixels_planned} pixels, {res.hardware_time_s:.3f} s of hardware time, {len(p)} valid points, "
              f"{int(box.sum())} on the box")
        print(f"range RMS against the truth at each point's t: box {rms(p['range'][box] - moved[box]):.3f} mm, "
              f"wall {rms(p['range'][~box] - moved[~box]):.3f} mm")
        still = box & (frozen < 5.0)
        print(f"against the frozen t = 0 scene: box RMS {rms(p['range'][still] - frozen[still]):.1f} mm; "
              f"{int(np.sum(box & (frozen >= 5.0)))} box points where the frozen box is not")
        print(f"radial velocity error on the box: max {np.max(np.abs(p['velocity'][box] - d[box] @ V_MPS)):.4f} m/s")
        print(f"casts: {casts} pixels into the static targets (once each), {moving_casts} beams into the moving box "
              f"({moving_casts / res.pixels_planned:.2f} per pixel: a switch transition lights two)")
    finally:
        inst.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
