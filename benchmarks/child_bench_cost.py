"""What a child bench (``lidar-sim``) costs per scan: CPU (user and system) and RSS, beside the daemon side.

``python benchmarks/child_bench_cost.py --scans 20`` runs small scans of the daemon's job code
(lidard.jobs.ScanWorker, the soak's ROI, its non-latching faults cycled) against a real ``lidar-sim``
child process, and prints one JSON line a scan and a summary: the child's CPU per scan (user and system
time from /proc, the scans after ``--skip`` warm-up ones), this process's (the daemon side), and the
child's RSS, anonymous and huge-page memory; ``--region`` scans eight full rows at 10 averages instead
(larger reads); ``--idle-s S`` reports the child's memory again after S s idle. CPU time, not wall time: the figures hold on a loaded
machine. To compare two versions of the code, run the script from each tree (the child bench is
started from the current directory's code): ``cd OLD && PYTHONPATH=$PWD python NEW/benchmarks/
child_bench_cost.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

SCAN = {"pattern": "roi", "rows": (40, 44), "cols": (48, 56), "max_range_m": 2.0}
# --region: a larger read, every column of eight rows at 10 averages (band_and_cores.py's region, shorter)
REGION = {"pattern": "roi", "rows": (40, 48), "cols": (0, 128), "averages": 10, "max_range_m": 2.0}
FAULTS: list[tuple[str, dict[str, Any]] | None] = [
    None, ("serial_drop", {"rate": 1e-3}), None, ("usb_timeout", {"device": "digitizer", "n": 2}),
    None, ("modbus_exception", {"code": 6, "n": 2}), ("serial_disconnect", {"reconnect_after_s": 0.05}),
    None, ("usb_disconnect", {"device": "digitizer", "n": 1})]


def child_bench_pid() -> int:
    """The ``lidar-sim`` child of this process."""
    me = os.getpid()
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            if b"sim_devices.bench.bench" not in (p / "cmdline").read_bytes():
                continue
            if int((p / "stat").read_text().rsplit(") ", 1)[1].split()[1]) == me:
                return int(p.name)
        except (OSError, IndexError, ValueError):
            continue
    raise RuntimeError("child_bench_cost: no lidar-sim child process found")


def process_figures(pid: int) -> dict[str, float]:
    """CPU seconds (user, system) and memory (MB: RSS, anonymous, huge pages) of ``pid``."""
    fields = (Path(f"/proc/{pid}/stat").read_text().rsplit(") ", 1)[1]).split()
    tick = os.sysconf("SC_CLK_TCK")
    out = {"user_s": int(fields[11]) / tick, "system_s": int(fields[12]) / tick}
    names = {"Rss:": "rss_mb", "Anonymous:": "anon_mb", "AnonHugePages:": "huge_mb"}
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
        parts = line.split()
        if parts and parts[0] in names:
            out[names[parts[0]]] = int(parts[1]) / 1024
    return out


def run(scans: int, skip: int, scan: dict[str, Any] = SCAN, idle_s: float = 0.0) -> dict[str, Any]:
    from lidard.config import CONFIG_DIR, load_config
    from lidard.instrument import ScanRequest, open_instrument
    from lidard.jobs import ScanWorker
    from lidard.store import Store

    cfg = load_config(CONFIG_DIR / "sim.toml")
    inst = open_instrument(cfg, bench="child")
    pid = child_bench_pid()
    rows: list[dict[str, Any]] = []
    idle: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="child-bench-cost-") as tmp:
        store = Store(Path(tmp) / "data")
        worker = ScanWorker(inst, store, laser=cfg.laser, max_queue=1, optics=cfg.optics(),
                            recalibrate_delta_c=cfg.scan.recalibrate_delta_c)
        worker.start()
        try:
            for k in range(scans):
                fault = FAULTS[k % len(FAULTS)]
                if fault is not None:
                    inst.inject_fault(fault[0], **fault[1])
                rec = worker.submit_scan(ScanRequest(**scan))
                final = worker.wait(rec.id, timeout_s=600)
                inst.clear_faults()
                row = {"scan": k, "state": final.state, "daemon_cpu_s": time.process_time(),
                       **process_figures(pid)}
                rows.append(row)
                print(json.dumps({key: round(v, 3) if isinstance(v, float) else v for key, v in row.items()}),
                      flush=True)
            if idle_s > 0:      # the bench idle (lidar-sim gives its heaps' free pages back)
                time.sleep(idle_s)
                idle = process_figures(pid)
        finally:
            worker.stop()
            store.close()
            inst.close()
    a, b = rows[min(skip, len(rows) - 2)], rows[-1]
    n = b["scan"] - a["scan"]
    return {"scans": scans, "measured_scans": n, "states": sorted({r["state"] for r in rows}),
            "bench_user_s_per_scan": (b["user_s"] - a["user_s"]) / n,
            "bench_system_s_per_scan": (b["system_s"] - a["system_s"]) / n,
            "daemon_side_cpu_s_per_scan": (b["daemon_cpu_s"] - a["daemon_cpu_s"]) / n,
            "bench_rss_mb": b["rss_mb"], "bench_anon_mb": b["anon_mb"], "bench_huge_mb": b["huge_mb"],
            **({"bench_rss_mb_after_idle": idle["rss_mb"], "bench_anon_mb_after_idle": idle["anon_mb"]} if idle else {}),
            "load": os.getloadavg()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scans", type=int, default=20, help="scans to run")
    ap.add_argument("--skip", type=int, default=2, help="warm-up scans left out of the per-scan figures")
    ap.add_argument("--region", action="store_true",
                    help="scan rows 40:48, every column, 10 averages (larger reads) instead of the soak's small ROI")
    ap.add_argument("--idle-s", type=float, default=0.0,
                    help="after the scans, leave the bench idle this long and report its memory again")
    args = ap.parse_args(argv)
    if not sys.platform.startswith("linux"):
        ap.error("reads /proc: Linux only")
    if args.skip < 0 or args.scans < args.skip + 2:
        ap.error(f"--scans must be at least --skip + 2 and --skip >= 0, got --scans {args.scans} --skip {args.skip}")
    if not 0 <= args.idle_s <= 600:
        ap.error(f"--idle-s must be 0-600 s, got {args.idle_s}")
    res = run(args.scans, args.skip, REGION if args.region else SCAN, args.idle_s)
    print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in res.items()}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
