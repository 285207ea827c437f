"""Benchmark: reprocessing a recorded scan on Dask, 1 and 2 worker processes vs in process (issue 17).

Records one ROI on the embedded simulated bench (CAL-letters scene, as benchmarks/raw_replay.py), then
reprocesses its raw capture (lidard.jobs.reprocess.reprocess_scan, one Zarr chunk per task) in this
process and on a LocalCluster of 1 and 2 worker processes (lidard.offline.cluster.mapper). Measures
the pure DSP time per chunk (reprocess_chunk in process), the client's serial part (reading nothing,
merging, writing the cloud and sidecar: in-process wall minus the chunks' DSP), the scheduling
overhead per task (trivial tasks through the same mapper), and the whole cost of one chunk task on
Dask (1-worker wall minus the serial part, per chunk: DSP + scheduling + reading + sending points
back). The MODEL (not a measurement) of W workers for a scan of C chunks of P pixels in all is

    T(W) = max(f * P + ceil(C / W) * t_task,  C * t_sched,  bytes / B)

f the serial seconds per pixel, t_task the Dask cost per chunk, t_sched the per-task overhead (the
scheduler hands out one task per t_sched at best), B an ASSUMED aggregate read bandwidth of the
shared store (--bandwidth-gbps, default 1 GB/s: one 10 GbE NFS server). The model is checked
against the measured 2-worker run before it is used for 10 and 100 workers on a larger scan
(--model-chunks, default 1000 chunks of this scan's size). Prints whether every Dask result equals
the in-process cloud.

    python benchmarks/raw_replay_dask.py [--rows 32:96] [--cols 32:96] [--repeat 3] [--bandwidth-gbps 1]
                                         [--model-chunks 1000]
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time

import numpy as np
from raw_replay import REPO, _machine, _range, _scan


def _best(fn, repeat: int) -> tuple[float, object]:
    best, res = math.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = fn()
        best = min(best, time.perf_counter() - t0)
    return best, res


def run(rows, cols, repeat: int) -> dict:
    from lidard.cli.embedded import embedded
    from lidard.config import load_config
    from lidard.offline.cluster import mapper, open_client
    from lidard.outputs import read_points
    from lidard.raw import chunk_count
    from lidard.raw.capture import RAW_NAME
    from lidard.raw.replay import reprocess_chunk
    from lidard.jobs.reprocess import reprocess_scan

    cfg = load_config(str(REPO / "config" / "sim.toml"))
    scene = str(REPO / "config" / "scenes" / "cal_letters.toml")
    body = {"pattern": "roi", "rows": rows, "cols": cols, "averages": 1, "max_range_m": 2.0,
            "formats": ["npz"], "record_raw": True}
    out: dict = {"machine": _machine(), "load": os.getloadavg()}
    with tempfile.TemporaryDirectory(prefix="raw-dask-") as tmp:
        with embedded(argparse.Namespace(data_dir=tmp), cfg, scene_path=scene) as (worker, store, _inst):
            rec = _scan(worker, body)
            pts = lambda r: read_points(store.data_dir / r.files["npz"])      # noqa: E731
            ref = pts(rec)
            out.update(pixels=rec.pixels_scanned, raw_bytes=rec.raw_bytes,
                       chunks=chunk_count(store.scan_dir(rec.id) / RAW_NAME))
            out["inproc_s"], r0 = _best(lambda: reprocess_scan(store, rec.id), repeat)
            raw = str(store.scan_dir(rec.id) / RAW_NAME)
            out["chunk_dsp_s"] = sum(_best(lambda: reprocess_chunk(raw, i), repeat)[0]
                                     for i in range(out["chunks"])) / out["chunks"]
            same = [np.array_equal(pts(r0), ref)]
            for w in (1, 2):
                with open_client(n_workers=w, processes=True) as c:
                    m = mapper(c)
                    m(abs, range(2 * w))                                     # workers up before timing
                    out[f"dask{w}_s"], r = _best(lambda: reprocess_scan(store, rec.id, map_fn=m), repeat)
                    same.append(np.array_equal(pts(r), ref))
                    n_tasks = 200
                    t, _ = _best(lambda: m(abs, range(n_tasks)), repeat)
                    out[f"sched{w}_s"] = t / n_tasks
            out["identical"] = all(same)
    return out


def costs(r: dict) -> dict:
    """The model's inputs from the measurements: serial s/pixel, Dask s/chunk, scheduler s/task."""
    serial_s = max(r["inproc_s"] - r["chunks"] * r["chunk_dsp_s"], 0.0)
    return {"f": serial_s / r["pixels"], "t_task": (r["dask1_s"] - serial_s) / r["chunks"],
            "t_sched": r["sched2_s"], "bytes_per_chunk": r["raw_bytes"] / r["chunks"],
            "px_per_chunk": r["pixels"] / r["chunks"]}


def model_s(k: dict, workers: int, chunks: int, bandwidth_bps: float) -> float:
    """Modelled wall seconds of a scan of ``chunks`` chunks (this scan's chunk size) on ``workers``."""
    pixels = chunks * k["px_per_chunk"]
    return max(k["f"] * pixels + math.ceil(chunks / workers) * k["t_task"], chunks * k["t_sched"],
               chunks * k["bytes_per_chunk"] / bandwidth_bps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=_range, default=[32, 96], help="ROI rows A:B (default 32:96)")
    ap.add_argument("--cols", type=_range, default=[32, 96], help="ROI columns A:B (default 32:96)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each measurement; the best is shown")
    ap.add_argument("--model-chunks", type=int, default=1000, help="chunks of the modelled large scan")
    ap.add_argument("--bandwidth-gbps", type=float, default=1.0,
                    help="ASSUMED aggregate read bandwidth of the shared store for the model, GB/s")
    a = ap.parse_args()
    r = run(a.rows, a.cols, a.repeat)
    n = r["pixels"]
    print(f"machine: {r['machine']}; load average {r['load'][0]:.2f} {r['load'][1]:.2f} {r['load'][2]:.2f}")
    print(f"scan: {n} pixels, raw capture {r['raw_bytes'] / 1e6:.1f} MB in {r['chunks']} chunks "
          f"({r['raw_bytes'] / r['chunks'] / 1e6:.2f} MB/chunk)")
    print(f"{'measured, best of ' + str(a.repeat):34s}{'wall s':>9s}{'pixels/s':>11s}{'vs in-process':>15s}")
    for name, key in (("in process", "inproc_s"), ("Dask, 1 worker process", "dask1_s"),
                      ("Dask, 2 worker processes", "dask2_s")):
        print(f"{name:34s}{r[key]:9.3f}{n / r[key]:11.0f}{r['inproc_s'] / r[key]:14.2f}x")
    k = costs(r)
    print(f"DSP per chunk (in process) {r['chunk_dsp_s'] * 1e3:.1f} ms; client serial part "
          f"{k['f'] * n * 1e3:.1f} ms ({k['f'] * 1e6:.2f} us/pixel); Dask cost per chunk task "
          f"{k['t_task'] * 1e3:.1f} ms; scheduling overhead per task {r['sched1_s'] * 1e3:.2f} ms (1 worker), "
          f"{r['sched2_s'] * 1e3:.2f} ms (2 workers)")
    bw = a.bandwidth_gbps * 1e9
    t2 = model_s(k, 2, r["chunks"], bw)
    print(f"model check, this scan on 2 workers: {t2:.3f} s modelled vs {r['dask2_s']:.3f} s measured")
    c = a.model_chunks
    print(f"MODEL (not measured): {c} chunks = {c * k['px_per_chunk']:.0f} pixels, "
          f"{c * k['bytes_per_chunk'] / 1e9:.2f} GB; store bandwidth {a.bandwidth_gbps:g} GB/s assumed")
    t1 = model_s(k, 1, c, bw)
    for w in (1, 2, 10, 100):
        t = model_s(k, w, c, bw)
        print(f"  {w:4d} workers: {t:8.2f} s, {c * k['px_per_chunk'] / t:9.0f} pixels/s, x{t1 / t:.1f} vs 1 worker")
    print(f"Dask results identical to the in-process cloud: {r['identical']}")


if __name__ == "__main__":
    main()
