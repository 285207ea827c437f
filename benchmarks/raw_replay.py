"""Benchmark: record a scan's raw segments, then reprocess them; is replay faster than scanning? (issue 16)

On the embedded simulated bench (CAL-letters scene) through the daemon's own job path
(lidard.jobs.ScanWorker over lidard.store.Store, as ``lidarctl scan --sim`` runs it): a warm-up
scan (the chirp linearization, §2.2, happens once), then the same ROI scanned without and with
``record_raw``, then the recorded scan reprocessed with its own settings (in this process, and on
a pool of processes, one chunk per task). Prints wall times, pixels/s, the ratio scan/replay, the
cost of recording, the capture's size, and whether the replayed points equal the scanned ones.

Wall time of the scan includes the simulated bench's own work (ray casting, beat synthesis, the
byte-level device models) on the same cores; the hardware time is what the real instrument would
take (the FPGA's pixel clock, the chirps).

    python benchmarks/raw_replay.py [--rows 32:96] [--cols 32:96] [--averages 1] [--workers 2] [--repeat 3]
                                    [--phase-noise auto|on|off]
"""

from __future__ import annotations

import argparse
import concurrent.futures
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _range(text: str) -> list[int]:
    a, b = (int(x) for x in text.split(":"))
    return [a, b]


def _scan(worker, body: dict):
    from lidard.jobs import request_from_dict
    rec = worker.submit_scan(request_from_dict(body))
    final = worker.wait(rec.id)
    if final.state != "done":
        raise SystemExit(f"scan {rec.id} ended {final.state}: {final.error}")
    return final


def _machine() -> str:
    try:
        from benchmarks.machine import machine_facts
    except ImportError:       # run as a script: benchmarks/ itself is on sys.path
        from machine import machine_facts
    f = machine_facts()
    model = f["cpu_model"] or "unknown CPU"
    return f"{model}, {f['cpus']} cores, Python {f['python']}, numpy {np.__version__}"


def run(rows: list[int], cols: list[int], averages: int, workers: int, repeat: int, phase_noise: str) -> dict:
    from lidard.cli.embedded import embedded
    from lidard.config import load_config
    from lidard.outputs import read_points
    from lidard.raw import chunk_count
    from lidard.raw.capture import RAW_NAME
    from lidard.jobs.reprocess import reprocess_scan

    cfg = load_config(str(REPO / "config" / "sim.toml"))
    scene = str(REPO / "config" / "scenes" / "cal_letters.toml")
    body = {"pattern": "roi", "rows": rows, "cols": cols, "averages": averages, "max_range_m": 2.0,
            "formats": ["npz"], "phase_noise_compensation": phase_noise}
    out: dict = {"machine": _machine()}
    with tempfile.TemporaryDirectory(prefix="raw-replay-") as tmp:
        args = argparse.Namespace(data_dir=tmp)
        with embedded(args, cfg, scene_path=scene) as (worker, store, _inst):
            _scan(worker, {**body, "rows": [rows[0], rows[0] + 1], "cols": [cols[0], cols[0] + 1]})  # linearize
            scans, recs = [], []
            for _ in range(repeat):      # interleaved, best of each: the machine is shared
                scans.append(_scan(worker, body))
                recs.append(_scan(worker, {**body, "record_raw": True}))
            rec = recs[-1]
            replays, pooled = [], []
            with concurrent.futures.ProcessPoolExecutor(workers) as pool:
                list(pool.map(abs, range(workers)))           # start the workers before timing
                for _ in range(repeat):
                    t0 = time.perf_counter()
                    replays.append((reprocess_scan(store, rec.id), time.perf_counter() - t0))
                    t0 = time.perf_counter()
                    pooled.append((reprocess_scan(store, rec.id, map_fn=pool.map), time.perf_counter() - t0))
            ref = read_points(store.data_dir / rec.files["npz"])
            identical = all(np.array_equal(read_points(store.data_dir / r.files["npz"]), ref)
                            for r, _ in replays + pooled)
            n = rec.pixels_scanned
            out.update(pixels=n, points=rec.points, hardware_s=rec.hardware_time_s,
                       scan_s=min(s.wall_time_s for s in scans), scan_raw_s=min(s.wall_time_s for s in recs),
                       raw_mb=rec.raw_bytes / 1e6, chunks=chunk_count(store.scan_dir(rec.id) / RAW_NAME),
                       replay_s=min(t for _, t in replays), pool_s=min(t for _, t in pooled), workers=workers,
                       identical=identical, repeat=repeat)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=_range, default=[32, 96], help="ROI rows A:B (default 32:96, 48 bonded)")
    ap.add_argument("--cols", type=_range, default=[32, 96], help="ROI columns A:B (default 32:96)")
    ap.add_argument("--averages", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2, help="processes of the pooled replay (default 2)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each measurement; the best is shown")
    ap.add_argument("--phase-noise", choices=("auto", "on", "off"), default="auto",
                    help="phase-noise compensation of the scans (on: the monitor MZI is recorded too)")
    a = ap.parse_args()
    r = run(a.rows, a.cols, a.averages, a.workers, a.repeat, a.phase_noise)
    n = r["pixels"]
    print(f"machine: {r['machine']}")
    print(f"ROI {a.rows[0]}:{a.rows[1]} x {a.cols[0]}:{a.cols[1]}, {n} pixels, {a.averages} average(s), "
          f"phase-noise compensation {a.phase_noise}, {r['points']} points; hardware time {r['hardware_s']:.3f} s")
    print(f"{'best of ' + str(r['repeat']):32s}{'wall s':>9s}{'pixels/s':>11s}")
    for name, s in (("scan (no raw)", r["scan_s"]), ("scan + record_raw", r["scan_raw_s"]),
                    ("reprocess, in process", r["replay_s"]),
                    (f"reprocess, {r['workers']} processes", r["pool_s"])):
        print(f"{name:32s}{s:9.3f}{n / s:11.0f}")
    print(f"raw capture: {r['raw_mb']:.1f} MB ({r['raw_mb'] * 1e6 / n / 1e3:.1f} kB/pixel), {r['chunks']} chunks")
    print(f"recording cost: x{r['scan_raw_s'] / r['scan_s']:.2f} scan wall time; "
          f"replay is x{r['scan_raw_s'] / r['replay_s']:.1f} faster than the recorded scan "
          f"(x{r['scan_raw_s'] / r['pool_s']:.1f} on {r['workers']} processes)")
    print(f"replayed points identical to the scan's: {r['identical']}")


if __name__ == "__main__":
    main()
