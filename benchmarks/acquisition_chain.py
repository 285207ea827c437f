"""Where the acquisition chain's CPU goes: one scan on the embedded simulated bench, its CPU by
thread group and, on the acquiring (scan) thread, by stage; the Modbus requests the controller
simulator answered and the safety watch's own polls.

    python benchmarks/acquisition_chain.py [--rows 0:128] [--priority] [--json]

The default is the full CAL frame (12,288 pixels x 10 averages, default band). Stage figures are the
scan thread's CPU inside wrapped functions (inclusive: a stage contains the ones it calls, e.g. the
digitizer read contains the bench's capture); thread groups come from /proc/self/task
(band_and_cores.ThreadCpu), the DSP worker processes from their /proc stat. A tree other than this
one is measured by putting it first on PYTHONPATH (the wrapped names exist on main since 5c4a3c3).
"""

from __future__ import annotations

import argparse
import collections
import importlib
import inspect
import json
import os
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: (module, qualified name, label) of the scan thread's stages, outermost first
STAGES = [
    ("drivers.digitizer.driver", "DigitizerDriver.read_segments", "digitizer read (all below)"),
    ("sim_devices.digitizer.device", "SimDigitizer._make_batch", "  simulated digitizer batch"),
    ("sim_devices.bench.capture", "SegmentSynthesizer._capture", "    bench capture"),
    ("sim_devices.fpsa.device", "FpgaSim.triggers_since", "      FPGA triggers and lit beams"),
    ("sim_devices.bench.capture", "SegmentSynthesizer._beat_hits", "      world hits (with look-ahead cast)"),
    ("sim_devices.bench.capture", "SegmentSynthesizer._synthesize", "      synthesis hand-off (CPU, not waits)"),
    ("drivers.digitizer.driver", "DigitizerDriver._validate", "  driver checks (CRCs, headers)"),
    ("lidard.instrument.scan_loop", "ScanLoop.safety_stop", "safety check per read"),
    ("lidard.instrument.scan_loop", "ScanLoop._accept", "accept (hand to the DSP)"),
]


def _wrap(acc: dict, calls: collections.Counter, module: str, qual: str, label: str) -> None:
    owner = importlib.import_module(module)
    *path, name = qual.split(".")
    for p in path:
        owner = getattr(owner, p)
    fn = getattr(owner, name)

    def timed(*a, **k):
        if threading.current_thread() is not threading.main_thread():
            return fn(*a, **k)
        t = time.thread_time()
        try:
            return fn(*a, **k)
        finally:
            acc[label] += time.thread_time() - t
            calls[label] += 1

    static = isinstance(inspect.getattr_static(owner, name), staticmethod)
    setattr(owner, name, staticmethod(timed) if static else timed)


def measure(rows: tuple[int, int]) -> dict:
    from benchmarks.band_and_cores import REGION, ThreadCpu, _instrument, _pids_cpu, load
    from benchmarks.band_and_cores import REPO as TREE       # the tree measured (first on PYTHONPATH)
    from lidard import dsp_pool
    from lidard.config import load_config
    from lidard.instrument import ScanRequest
    from sim_devices.controller.device import ControllerSim

    acc: dict[str, float] = collections.defaultdict(float)
    calls: collections.Counter = collections.Counter()
    for module, qual, label in STAGES:
        _wrap(acc, calls, module, qual, label)
    cfg = load_config(TREE / "config" / "sim.toml")
    inst, cal = _instrument(cfg)
    dsp_pool.warm()
    sims = [o for o in __import__("gc").get_objects() if isinstance(o, ControllerSim)]
    req0 = sum(s.requests_received for s in sims)
    acc.clear()
    calls.clear()
    pool = dsp_pool.dsp_pool()
    pids = pool.pids if pool is not None else []
    polls = collections.Counter()            # flags reads by thread (the watch's thread: its polls)
    read_flags = inst.safety.read_flags

    def counted(*a, **k):
        polls[threading.current_thread().name] += 1
        return read_flags(*a, **k)

    inst.safety.read_flags = counted
    with ThreadCpu() as tc:
        t, c, th, w = time.perf_counter(), time.process_time(), time.thread_time(), _pids_cpu(pids)
        res = inst.run_scan(ScanRequest(**{**REGION, "rows": rows}), lambda p: None, threading.Event(), cal)
        wall, cpu, th = time.perf_counter() - t, time.process_time() - c, time.thread_time() - th
        workers = _pids_cpu(pids) - w
    requests = sum(s.requests_received for s in sims) - req0
    inst.close()
    reads = calls["safety check per read"]
    return {"rows": list(rows), "pixels": res.pixels_scanned, "points": int(len(res.points)),
            "hardware_s": res.hardware_time_s, "wall_s": round(wall, 3), "cpu_s": round(cpu + workers, 3),
            "scan_thread_cpu_s": round(th, 3), "reads": reads,
            "thread_cpu_s": {**tc.groups(), "dsp worker processes": round(workers, 2)},
            "scan_thread_stages_cpu_s": {label: round(acc[label], 3) for _, _, label in STAGES},
            "modbus_requests": requests, "watch_polls": polls["lidard-safety-watch"],
            "load": round(load(), 1)}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", default="0:128", help="pattern rows a:b (all 128 columns); default the full frame")
    ap.add_argument("--priority", action="store_true",
                    help="root: run in a session of its own at autogroup nice -20 (band_and_cores.py --priority)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    if a.priority:
        from benchmarks.band_and_cores import _high_priority
        _high_priority()
    rows = tuple(int(x) for x in a.rows.split(":"))
    out = measure((rows[0], rows[1]))
    if a.json:
        print(json.dumps(out))
        return
    print(f"{out['pixels']} pixels, {out['reads']} reads, {out['hardware_s']:.1f} s of hardware time; "
          f"wall {out['wall_s']:.2f} s, CPU {out['cpu_s']:.2f} s (load {out['load']})")
    print("CPU by thread group (s):", json.dumps(out["thread_cpu_s"]))
    print("scan thread by stage (CPU s, inclusive):")
    for k, v in out["scan_thread_stages_cpu_s"].items():
        print(f"  {k:45s} {v:7.3f}  ({1e3 * v / max(1, out['reads']):.2f} ms a read)")
    print(f"Modbus requests answered by the controller simulator: {out['modbus_requests']}; "
          f"safety watch polls: {out['watch_polls']}")


if __name__ == "__main__":
    if str(REPO) not in sys.path:
        sys.path.append(str(REPO))      # after PYTHONPATH: another tree put first is the one measured
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    main()
