"""End-to-end frame benchmark: wall time against modelled hardware time, and peak memory.

Runs a full scan on the embedded simulated bench (bench included in the timing: synthesis, wire
protocols, DSP) and prints the real-time factor (hardware frame time / wall time) and the peak RSS.
The hardware time is the digitizer's trigger clock (virtual clock of the FPGA model, §4.3.3
settle + triggers per pixel), so it is what the real instrument would take for the same frame.

    python benchmarks/frame.py [--averages 10] [--rows 0:128] [--max-range 2] [--scene ...] [--json]

``run_frame(...)`` returns the figures as a dict (used by ``python -m benchmarks``).
"""

from __future__ import annotations

import argparse
import json
import threading
import time

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument import open_instrument
from lidard.instrument import ScanRequest

DEFAULT_SCENE = str(CONFIG_DIR / "scenes" / "cal_letters.toml")


def reset_peak_rss() -> None:
    """Start a new resident-set high-water mark for this process (Linux: clear_refs 5)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


def peak_rss_mb() -> float:
    """This process's resident-set high-water mark (VmHWM) in MB.

    Not ru_maxrss: on Linux that survives fork and exec, so a child would report its parent's peak.
    """
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_frame(averages: int = 10, rows: tuple[int, int] = (0, 128), cols: tuple[int, int] = (0, 128),
              max_range_m: float = 2.0, scene: str = DEFAULT_SCENE) -> dict:
    """One linearization and one ROI scan on a fresh embedded bench; wall and hardware times."""
    cfg = load_config(CONFIG_DIR / "sim.toml")
    inst = open_instrument(cfg, scene_path=scene, bench="embedded")
    try:
        t = time.perf_counter()
        cal = inst.linearize()
        t_cal = time.perf_counter() - t
        req = ScanRequest(pattern="roi", rows=tuple(rows), cols=tuple(cols), averages=averages,
                          max_range_m=max_range_m)
        t, c = time.perf_counter(), time.process_time()
        res = inst.run_scan(req, lambda p: None, threading.Event(), cal)
        wall, cpu = time.perf_counter() - t, time.process_time() - c
    finally:
        inst.close()
    # the high-water mark of this process's memory (VmHWM): it includes whatever ran before in it
    peak_mb = peak_rss_mb()
    return {"pixels": res.pixels_scanned, "averages": averages, "max_range_m": max_range_m,
            "adc_rate_hz": res.meta["adc"]["sample_rate_hz"], "record_length": res.meta["adc"]["record_length"],
            "points": len(res.points), "linearization_wall_s": t_cal, "hardware_s": res.hardware_time_s,
            "wall_s": wall, "cpu_s": cpu, "realtime_factor": res.hardware_time_s / wall,
            "realtime_factor_cpu": res.hardware_time_s / cpu, "peak_rss_mb": peak_mb}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--averages", type=int, default=10)
    ap.add_argument("--rows", default="0:128")
    ap.add_argument("--cols", default="0:128")
    ap.add_argument("--max-range", type=float, default=2.0)
    ap.add_argument("--scene", default=DEFAULT_SCENE)
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    args = ap.parse_args(argv)
    r = run_frame(args.averages, tuple(map(int, args.rows.split(":"))), tuple(map(int, args.cols.split(":"))),
                  args.max_range, args.scene)
    if args.json:
        print(json.dumps(r))
        return
    print(f"pixels {r['pixels']}  averages {r['averages']}  max_range {r['max_range_m']} m  "
          f"adc {r['adc_rate_hz'] / 1e6:.2f} MS/s x {r['record_length']} samples")
    print(f"points {r['points']}  linearization {r['linearization_wall_s']:.2f} s wall")
    print(f"hardware frame time {r['hardware_s']:.3f} s  wall {r['wall_s']:.3f} s  "
          f"real-time factor {r['realtime_factor']:.2f} (on CPU time {r['realtime_factor_cpu']:.2f})  peak RSS {r['peak_rss_mb']:.0f} MB")


if __name__ == "__main__":
    main()
