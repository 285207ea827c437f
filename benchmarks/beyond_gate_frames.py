"""Benchmark: false points in full frames with a bright wall beyond the range gate (hold-out check).

A wall beyond the gate has its ramp beats cut by the gate and the decimation filter, yet it still beats
in the three-segment chirp's held (CW) segment within the Doppler band. Every valid point of such a
frame is false (nothing lies inside the gate). The detection is set for ``scan.pfa`` (1e-11) false points
a range cell: ~1e-5 a frame of 12,288 pixels x ~140 gate cells x 3 slots. Each row: one wall, one
bench seed (``sim.seed``; each seed its own embedded bench, linearized), a full frame at the default
config (2 m gate, 0.4 m/s band, tolerances off): valid points, their ranges, and the rate per pixel.

Run: python benchmarks/beyond_gate_frames.py [--walls 3.0,5.5,8.0] [--seeds 1,2,3] [--albedo 0.5]
"""

from __future__ import annotations

import argparse
import os
import threading
import time

import numpy as np

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument


def wall(z_m: float, albedo: float) -> dict:
    return {"target": [{"kind": "plane", "point": [0.0, 0.0, z_m], "normal": [0.0, 0.0, -1.0],
                        "reflectivity": albedo}]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walls", default="3.0,5.5,8.0", help="wall distances, m (default 3.0,5.5,8.0)")
    ap.add_argument("--seeds", default="1,2,3", help="bench seeds (default 1,2,3)")
    ap.add_argument("--albedo", type=float, default=0.5)
    a = ap.parse_args(argv)
    walls = [float(w) for w in a.walls.split(",")]
    print(f"load {os.getloadavg()[0]:.1f}; walls {walls} m, albedo {a.albedo}")
    print(f"{'wall m':>7} {'seed':>5} {'pixels':>7} {'valid':>6} {'per pixel':>10}  ranges of the valid points (m)")
    total_valid = total_pix = 0
    for seed in (int(s) for s in a.seeds.split(",")):
        cfg = load_config("config/sim.toml", environ={"LIDARD__SIM__TOLERANCES__ENABLED": "false",
                                                      "LIDARD__SIM__SEED": str(seed)})
        inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
        try:
            cal = inst.linearize()
            for z in walls:
                inst.set_scene(wall(z, a.albedo))
                t = time.perf_counter()
                res = inst.run_scan(ScanRequest(max_range_m=2.0), lambda p: None, threading.Event(), cal)
                v = res.points[res.points["valid"] == 1]
                total_valid += len(v)
                total_pix += res.pixels_scanned
                print(f"{z:>7.1f} {seed:>5} {res.pixels_scanned:>7} {len(v):>6} {len(v) / res.pixels_scanned:>10.1e}  "
                      f"{[round(float(r), 3) for r in np.sort(v['range'])]}  ({time.perf_counter() - t:.1f} s)", flush=True)
        finally:
            inst.close()
    print(f"all: {total_valid} valid (false) points in {total_pix} pixels: {total_valid / max(total_pix, 1):.1e} a pixel")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
