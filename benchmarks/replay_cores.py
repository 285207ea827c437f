"""Where a raw replay's wall goes, per stage, on one core and on two (docs/measured/27_replay.md).

    python benchmarks/replay_cores.py [--capture DIR] [--keep DIR] [--rounds N] [--cold] [--codecs] [--priority] [--json]

A 10 m/s region scan (rows 40:56, every column, 10 averages; cal_letters scene, embedded bench) is
recorded raw (or ``--capture`` an existing one; ``--keep`` keeps the recording), then replayed in
alternated rounds:

* ``one core``: a fresh process pinned to one core (``taskset -c 0``), the replay's tasks run on its
  one thread (what ``lidard.raw.replay.local_map`` does there), each stage timed (CPU and wall):
  ``open`` (the capture's attributes and the task's FrameDsp), ``read`` (the task's chunks: the files
  read and decoded), ``dsp`` (FrameDsp.process), ``points`` (frame_points);
* ``two cores``: :func:`lidard.raw.replay.reprocess` on the DSP's worker processes (lidard.dsp_pool),
  its tasks timed the same way inside the workers (summed over both), the parent's wall and CPU, and
  the workers' CPU from /proc.

Each is against the digitizer's data rate: the recorded samples (pixels x averages x record length)
over the wall time, divided by the ADC's sample rate. The replayed points are compared with the
scan's (bytes). Round 0 warms the page cache and the workers and is not reported. The machine is
shared: the load average is printed with every round; ``--priority`` (root) runs in a scheduler
autogroup of its own at nice -20, as benchmarks/band_and_cores.py does.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

# the CPU of other processes, and a session of its own at autogroup nice -20: as band_and_cores.py measures
from benchmarks.band_and_cores import _high_priority, _pids_cpu  # noqa: E402
SCENE = str(REPO / "config" / "scenes" / "cal_letters.toml")
REQUEST = {"pattern": "roi", "rows": (40, 56), "cols": (0, 128), "averages": 10, "max_range_m": 2.0,
           "max_speed_mps": 10.0}
STAGES = ("open", "read", "dsp", "points")


def timed_task(raw_path: str, task_index: int, chunks_per_task: int, prefetch: bool = True):
    """One replay task as lidard.raw.replay.reprocess_task runs it (``prefetch``: it asks for the next
    task's chunk files as it does), each stage's (wall, CPU of the process: zarr reads on threads of its own) timed."""
    import numpy as np
    from lidard.raw.capture import RawCapture
    from lidard.raw.replay import replay_dsp
    t: dict[str, list[float]] = {}

    def lap(name, w, c):
        t[name] = [time.perf_counter() - w, time.process_time() - c]

    w, c = time.perf_counter(), time.process_time()
    cap = RawCapture(raw_path)
    rd = replay_dsp(cap.attrs)
    lap("open", w, c)
    w, c = time.perf_counter(), time.process_time()
    first = task_index * chunks_per_task
    stop = min(first + chunks_per_task, cap.n_chunks)
    ch = cap.chunks(first, stop)
    if prefetch and hasattr(cap, "prefetch"):       # (a tree before the prefetch: none)
        cap.prefetch(stop, stop + chunks_per_task)
    lap("read", w, c)
    w, c = time.perf_counter(), time.process_time()
    beat = ch.channel("beat", cap.channels, cap.averages)
    res = rd.dsp.process(beat, rd.lsb_v)
    lap("dsp", w, c)
    w, c = time.perf_counter(), time.process_time()
    from lidard.raw.points import frame_points
    pts = frame_points(res, ch.pixels, ch.t_s, ch.directions, ch.clipped, rd.dsp.measurement_delay_s(cap.averages))
    lap("points", w, c)
    return np.asarray(pts), t


def _sum_stages(parts) -> dict:
    out = {s: [0.0, 0.0] for s in STAGES}
    for _, t in parts:
        for s in STAGES:
            out[s][0] += t[s][0]
            out[s][1] += t[s][1]
    return {s: {"wall_s": round(v[0], 3), "cpu_s": round(v[1], 3)} for s, v in out.items()}


def _tasks(path: str) -> tuple[int, int]:
    from lidard.raw.capture import RawCapture
    from lidard.raw.replay import _chunks_per_task
    cap = RawCapture(path)
    k = _chunks_per_task(cap)
    return k, -(-cap.n_chunks // k)


def one_core(path: str, prefetch: bool = True) -> dict:
    """The replay on this process's one thread, stage by stage (run pinned to one core)."""
    import numpy as np
    k, n = _tasks(path)
    w, c = time.perf_counter(), time.process_time()
    parts = [timed_task(path, i, k, prefetch) for i in range(n)]
    pts = np.concatenate([p for p, _ in parts])
    wall, cpu = time.perf_counter() - w, time.process_time() - c
    ref = np.load(path + ".points.npy")
    return {"wall_s": wall, "cpu_s": cpu, "tasks": n, "stages": _sum_stages(parts),
            "identical_to_scan": bool(np.array_equal(pts, ref)), "cores": len(os.sched_getaffinity(0))}


def two_cores(path: str, prefetch: bool = True) -> dict:
    """The replay on the DSP's worker processes (the default local_map), each task timed in its worker."""
    import numpy as np
    from lidard import dsp_pool
    k, n = _tasks(path)
    pool = dsp_pool.dsp_pool()
    if pool is None or not pool.lease():
        raise SystemExit("no DSP pool here (one core?): the two-core replay needs two")
    try:
        pids = pool.pids
        w, c, cw = time.perf_counter(), time.process_time(), _pids_cpu(pids)
        parts = pool.map(timed_task, [(path, i, k, prefetch) for i in range(n)])
        pts = np.concatenate([p for p, _ in parts])
        wall, cpu, wcpu = time.perf_counter() - w, time.process_time() - c, _pids_cpu(pids) - cw
    finally:
        pool.unlease()
    ref = np.load(path + ".points.npy")
    return {"wall_s": wall, "cpu_s": cpu + wcpu, "parent_cpu_s": cpu, "workers_cpu_s": wcpu, "tasks": n,
            "workers": len(pids), "stages": _sum_stages(parts), "identical_to_scan": bool(np.array_equal(pts, ref))}


def record(path: Path) -> None:
    """A 10 m/s region scan recorded raw at ``path``; its points saved next to it (``.points.npy``)."""
    import numpy as np
    from lidard.config import load_config
    from lidard.instrument import ScanRequest, open_instrument
    from lidard.store import calcache
    cfg = load_config(REPO / "config" / "sim.toml")
    inst = open_instrument(cfg, scene_path=SCENE, bench="embedded")
    try:
        cal = calcache.load(cfg)
        if cal is None or cal.laser != cfg.laser:
            cal = inst.linearize()
            calcache.save(cfg, cal)
        res = inst.run_scan(ScanRequest(**REQUEST), lambda p: None, threading.Event(), cal, raw_path=path)
    finally:
        inst.close()
    np.save(str(path) + ".points.npy", res.points)


def _describe(path: str) -> dict:
    from lidard.raw.capture import RawCapture
    cap = RawCapture(path)
    rl, fs = int(cap.attrs["record_length"]), float(cap.attrs["adc"]["sample_rate_hz"])
    seg = json.loads((Path(path) / "segments" / "zarr.json").read_text())
    blosc = [c["configuration"] for c in seg["codecs"] if c["name"] == "blosc"]
    return {"pixels": cap.n_pixels, "averages": cap.averages, "record_length": rl, "fs_hz": fs,
            "samples": cap.n_pixels * cap.averages * rl, "chunks": cap.n_chunks,
            "codec": f"blosc {blosc[0]['cname']} {blosc[0]['shuffle']}" if blosc else seg["codecs"][-1]["name"],
            "bytes_on_disk": sum(f.stat().st_size for f in (Path(path) / "segments").rglob("*") if f.is_file())}


def codecs(path: str, repeats: int = 3) -> dict:
    """The capture's samples, chunk by chunk, through blosc-lz4 (level 1) byte-shuffled (captures
    before), bit-shuffled (now) and stored plain: bytes kept, encode and decode CPU (best of ``repeats``)."""
    import numpy as np
    from numcodecs import blosc
    from lidard.raw.capture import RawCapture
    cap = RawCapture(path)
    rows = cap.chunk_pixels * cap.averages
    seg = cap.chunks(0, cap.n_chunks).segments
    parts = [seg[i:i + rows] for i in range(0, len(seg), rows)]
    out = {}
    for name, shuffle in (("byte-shuffled", blosc.SHUFFLE), ("bit-shuffled", blosc.BITSHUFFLE), ("none", None)):
        enc_cpu, dec_cpu, enc = [], [], []
        for _ in range(repeats):
            c = time.process_time()
            enc = [p.tobytes() if shuffle is None else blosc.compress(p, b"lz4", 1, shuffle) for p in parts]
            enc_cpu.append(time.process_time() - c)
            c = time.process_time()
            for e, p in zip(enc, parts):
                if shuffle is not None:
                    blosc.decompress(e, np.empty_like(p))
            dec_cpu.append(time.process_time() - c)
        out[name] = {"ratio": sum(len(e) for e in enc) / seg.nbytes, "encode_cpu_s": min(enc_cpu),
                     "decode_cpu_s": min(dec_cpu)}
    return out


def evict(path: str) -> None:
    """Drop this capture's files from the page cache (``posix_fadvise`` DONTNEED; no other file is
    touched): the next replay reads them from the disk, as a capture recorded days ago is."""
    for f in Path(path).rglob("*"):
        if f.is_file():
            fd = os.open(f, os.O_RDONLY)
            try:
                os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
            finally:
                os.close(fd)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--capture", help="replay this capture (recorded by this script: DIR.points.npy beside it)")
    ap.add_argument("--keep", help="record the capture here and keep it")
    ap.add_argument("--rounds", type=int, default=3, help="alternated rounds of one core and two (after a warm-up)")
    ap.add_argument("--priority", action="store_true", help="root: a session of its own at autogroup nice -20")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--cold", action="store_true",
                    help="evict the capture's files from the page cache before every replay; each mode is run "
                         "with and without the replay's prefetch of the next task's chunk files")
    ap.add_argument("--codecs", action="store_true",
                    help="also the samples' bytes and encode/decode CPU byte-shuffled, bit-shuffled and plain")
    ap.add_argument("--one-core-child", help=argparse.SUPPRESS)
    ap.add_argument("--no-prefetch", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one_core_child:
        print(json.dumps(one_core(a.one_core_child, prefetch=not a.no_prefetch)))
        return
    if a.priority:
        _high_priority()
    with tempfile.TemporaryDirectory(prefix="replay-cores-") as tmp:
        path = a.capture or a.keep or str(Path(tmp) / "raw.zarr")
        if not a.capture:
            record(Path(path))
        d = _describe(path)
        out: dict = {"capture": d, "hardware_s": d["samples"] / d["fs_hz"], "rounds": []}
        if a.codecs:
            out["codecs"] = codecs(path)
        child = ["taskset", "-c", "0", sys.executable, str(Path(__file__).resolve()), "--one-core-child", path]
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        modes = [("one core", True), ("two cores", True)]
        if a.cold:
            modes += [("one core", False), ("two cores", False)]
        for r in range(a.rounds + 1):
            row: dict = {"round": r}
            for mode, prefetch in (modes if r % 2 else modes[::-1]):
                if a.cold:
                    evict(path)
                if mode == "one core":
                    argv_ = child + ([] if prefetch else ["--no-prefetch"])
                    res = json.loads(subprocess.run(argv_, env=env, check=True, capture_output=True, text=True).stdout)
                else:
                    res = two_cores(path, prefetch)
                if a.cold:
                    mode = f"{mode}, cold, {'prefetch' if prefetch else 'no prefetch'}"
                res["x_digitizer_rate"] = out["hardware_s"] / res["wall_s"]
                res["load"] = os.getloadavg()[0]
                row[mode] = res
            if r:
                out["rounds"].append(row)
                if not a.json:
                    print(json.dumps(row, default=float), flush=True)
    if a.json:
        print(json.dumps(out, default=float))
    else:
        print(json.dumps({k: v for k, v in out.items() if k != "rounds"}, default=float))


if __name__ == "__main__":
    main()
