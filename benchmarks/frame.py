"""End-to-end frame benchmark: wall time against modelled hardware time, and peak memory.

Runs a full scan on the embedded simulated bench (bench included in the timing: synthesis, wire
protocols, DSP) and prints the real-time factor (hardware frame time / wall time) and the peak RSS.

    python benchmarks/frame.py [--averages 10] [--rows 0:128] [--max-range 2] [--scene ...]
"""

from __future__ import annotations

import argparse
import resource
import threading
import time

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument import open_instrument
from lidard.instrument_api import ScanRequest


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--averages", type=int, default=10)
    ap.add_argument("--rows", default="0:128")
    ap.add_argument("--cols", default="0:128")
    ap.add_argument("--max-range", type=float, default=2.0)
    ap.add_argument("--scene", default=str(CONFIG_DIR / "scenes" / "cal_letters.toml"))
    args = ap.parse_args()
    cfg = load_config(CONFIG_DIR / "sim.toml")
    inst = open_instrument(cfg, scene_path=args.scene, bench="embedded")
    try:
        t = time.perf_counter()
        cal = inst.linearize()
        t_cal = time.perf_counter() - t
        r0, r1 = map(int, args.rows.split(":"))
        c0, c1 = map(int, args.cols.split(":"))
        req = ScanRequest(pattern="roi", rows=(r0, r1), cols=(c0, c1), averages=args.averages,
                          max_range_m=args.max_range)
        t = time.perf_counter()
        res = inst.run_scan(req, lambda p: None, threading.Event(), cal)
        wall = time.perf_counter() - t
    finally:
        inst.close()
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"pixels {res.pixels_scanned}  averages {args.averages}  max_range {args.max_range} m  "
          f"adc {res.meta['adc']['sample_rate_hz'] / 1e6:.2f} MS/s x {res.meta['adc']['record_length']} samples")
    print(f"points {len(res.points)}  linearization {t_cal:.2f} s wall")
    print(f"hardware frame time {res.hardware_time_s:.3f} s  wall {wall:.3f} s  "
          f"real-time factor {res.hardware_time_s / wall:.2f}  peak RSS {peak_mb:.0f} MB")


if __name__ == "__main__":
    main()
