"""End-to-end frame benchmark: wall time against modelled hardware time, and peak memory.

Runs a full scan on the embedded simulated bench (bench included in the timing: synthesis, wire
protocols, DSP) and prints the real-time factor (hardware frame time / wall time) and the peak RSS.
The hardware time is the digitizer's trigger clock (virtual clock of the FPGA model, §4.3.3
settle + triggers per pixel), so it is what the real instrument would take for the same frame.

    python benchmarks/frame.py [--averages 10] [--rows 0:128] [--max-range 2] [--max-speed M] [--scene ...] [--json]

``run_frame(...)`` returns the figures as a dict (used by ``python -m benchmarks``). With
``limit=True`` it also runs the limit kernel of the same scan (benchmarks/limit.py) in the same
process right after it and gives scan/limit ratios per stage: synthesis (the bench's capture:
world model + beat synthesis + front end), transport (the digitizer read minus that capture:
USB protocol, decoding), DSP (the frame DSP of every batch, points included) and points (writing
the PLY). Stage times are taken by wrapping those functions (wall and the scan thread's CPU time).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import tempfile
import threading
import time

from lidard.dsp_pool import cpu_time  # the DSP worker processes' CPU is a scan's too

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


@contextlib.contextmanager
def stage_timers():
    """Wrap the scan's stage functions; yield {stage: [wall_s, thread_cpu_s]} filled while inside."""
    import sim_devices.bench.bench as bench
    import sim_devices.world.synth_parallel as bench_capture   # where the bench's capture calls synthesize
    from lidard.instrument import acquisition, points
    acc: dict[str, list[float]] = {k: [0.0, 0.0] for k in ("capture", "beat_synthesis", "read", "dsp")}
    targets = [(bench.Bench, "capture", "capture"), (bench_capture, "synthesize", "beat_synthesis"),
               (acquisition.AcquisitionLifecycle, "read", "read"), (points.PointBuffer, "_process", "dsp")]

    def timed(fn, key):
        def wrapper(*a, **kw):
            t, c = time.perf_counter(), time.thread_time()
            try:
                return fn(*a, **kw)
            finally:
                acc[key][0] += time.perf_counter() - t
                acc[key][1] += time.thread_time() - c
        return wrapper

    saved = [(obj, name, getattr(obj, name)) for obj, name, _ in targets]
    for obj, name, key in targets:
        setattr(obj, name, timed(getattr(obj, name), key))
    try:
        yield acc
    finally:
        for obj, name, fn in saved:
            setattr(obj, name, fn)


def _stages(acc: dict, points_s: tuple[float, float]) -> dict:
    """Per-stage (wall, cpu) of the scan in the limit kernel's stage names."""
    cap, read = acc["capture"], acc["read"]
    return {"synthesis": tuple(cap), "transport": (read[0] - cap[0], read[1] - cap[1]),
            "dsp": tuple(acc["dsp"]), "points": points_s,
            "beat_synthesis_only": tuple(acc["beat_synthesis"])}


def _write_ply_timed(pts) -> tuple[float, float]:
    from lidard.outputs.ply import write_ply
    with tempfile.TemporaryDirectory(prefix="frame-") as d:
        t, c = time.perf_counter(), time.thread_time()
        write_ply(os.path.join(d, "frame.ply"), pts)
        return time.perf_counter() - t, time.thread_time() - c


def run_frame(averages: int = 10, rows: tuple[int, int] = (0, 128), cols: tuple[int, int] = (0, 128),
              max_range_m: float = 2.0, scene: str = DEFAULT_SCENE, limit: bool = False,
              max_speed_mps: float | None = None) -> dict:
    """One linearization and one ROI scan on a fresh embedded bench; wall and hardware times, the
    stage times, and (``limit``) the limit kernel of the same scan with scan/limit ratios.
    ``max_speed_mps``: the scan's Doppler band (None: the configuration's ``scan.max_speed_mps``)."""
    cfg = load_config(CONFIG_DIR / "sim.toml")
    inst = open_instrument(cfg, scene_path=scene, bench="embedded")
    try:
        t = time.perf_counter()
        cal = inst.linearize()
        t_cal = time.perf_counter() - t
        band = {} if max_speed_mps is None else {"max_speed_mps": float(max_speed_mps)}
        req = ScanRequest(pattern="roi", rows=tuple(rows), cols=tuple(cols), averages=averages,
                          max_range_m=max_range_m, **band)
        with stage_timers() as acc:
            t, c, own = time.perf_counter(), cpu_time(), time.process_time()
            res = inst.run_scan(req, lambda p: None, threading.Event(), cal)
            wall, cpu = time.perf_counter() - t, cpu_time() - c
            workers_cpu = cpu - (time.process_time() - own)      # the DSP worker processes' share
    finally:
        inst.close()
    stages = _stages(acc, _write_ply_timed(res.points))
    dsp_wall, dsp_cpu = stages["dsp"]
    stages["dsp"] = (dsp_wall, dsp_cpu + workers_cpu)      # a batch's DSP runs on the pool's processes
    # the high-water mark of this process's memory (VmHWM): it includes whatever ran before in it
    peak_mb = peak_rss_mb()
    out = {"pixels": res.pixels_scanned, "averages": averages, "max_range_m": max_range_m,
            "adc_rate_hz": res.meta["adc"]["sample_rate_hz"], "record_length": res.meta["adc"]["record_length"],
            "points": len(res.points), "linearization_wall_s": t_cal, "hardware_s": res.hardware_time_s,
            "wall_s": wall, "cpu_s": cpu, "realtime_factor": res.hardware_time_s / wall,
            "realtime_factor_cpu": res.hardware_time_s / cpu, "peak_rss_mb": peak_mb,
            "stages_wall_s": {k: v[0] for k, v in stages.items()}, "stages_cpu_s": {k: v[1] for k, v in stages.items()}}
    if limit:
        out.update(_with_limit(out, res.meta))
    return out


def _with_limit(f: dict, meta: dict) -> dict:
    """The limit kernel of the scan ``f`` described (same samples, ramps, points) and the ratios."""
    try:
        from benchmarks.limit import STAGES, run_limit, stage_ratios
    except ImportError:            # run as a script: benchmarks/ itself is on sys.path
        from limit import STAGES, run_limit, stage_ratios
    lim = run_limit(f["pixels"], f["averages"], f["record_length"], meta["adc"]["ramp_samples"],
                    channels=2 if meta["dsp"]["phase_noise_compensation"] else 1, points=f["points"],
                    use_fraction=meta["dsp"]["use_fraction"], fs_hz=f["adc_rate_hz"])
    scan_wall = {k: f["stages_wall_s"][k] for k in STAGES}
    scan_cpu = {k: f["stages_cpu_s"][k] for k in STAGES}
    return {"limit": lim, "ratio_wall": stage_ratios(scan_wall, lim["wall_s"]),
            "ratio_cpu": stage_ratios(scan_cpu, lim["cpu_s"]),
            # the whole scan (every stage, plus the scan loop, FPGA, settle) against the whole limit
            "ratio_scan_cpu": f["cpu_s"] / lim["total_cpu_s"], "ratio_scan_wall": f["wall_s"] / lim["total_wall_s"]}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--averages", type=int, default=10)
    ap.add_argument("--rows", default="0:128")
    ap.add_argument("--cols", default="0:128")
    ap.add_argument("--max-range", type=float, default=2.0)
    ap.add_argument("--max-speed", type=float, default=None,
                    help="the scan's Doppler band in m/s (default: the configuration's scan.max_speed_mps)")
    ap.add_argument("--scene", default=DEFAULT_SCENE)
    ap.add_argument("--limit", action="store_true", help="also run the limit kernel of the same scan, "
                    "then print scan/limit ratios per stage")
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    args = ap.parse_args(argv)
    r = run_frame(args.averages, tuple(map(int, args.rows.split(":"))), tuple(map(int, args.cols.split(":"))),
                  args.max_range, args.scene, limit=args.limit, max_speed_mps=args.max_speed)
    if args.json:
        print(json.dumps(r))
        return
    print(f"pixels {r['pixels']}  averages {r['averages']}  max_range {r['max_range_m']} m  "
          f"adc {r['adc_rate_hz'] / 1e6:.2f} MS/s x {r['record_length']} samples")
    print(f"points {r['points']}  linearization {r['linearization_wall_s']:.2f} s wall")
    print(f"hardware frame time {r['hardware_s']:.3f} s  wall {r['wall_s']:.3f} s  "
          f"real-time factor {r['realtime_factor']:.2f} (on CPU time {r['realtime_factor_cpu']:.2f})  peak RSS {r['peak_rss_mb']:.0f} MB")
    print("stage (wall s / cpu s): " + "  ".join(f"{k} {r['stages_wall_s'][k]:.2f}/{r['stages_cpu_s'][k]:.2f}"
                                                 for k in r["stages_wall_s"]))
    if args.limit:
        print("scan/limit on CPU time: " + "  ".join(f"{k} {v:.1f}x" for k, v in r["ratio_cpu"].items())
              + f"  whole scan {r['ratio_scan_cpu']:.1f}x")
        print("scan/limit on wall time: " + "  ".join(f"{k} {v:.1f}x" for k, v in r["ratio_wall"].items())
              + f"  whole scan {r['ratio_scan_wall']:.1f}x")


if __name__ == "__main__":
    main()
