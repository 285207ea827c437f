"""Load benchmark (issue 6): many observers polling a live daemon while a scan runs.

A real uvicorn server on 127.0.0.1 (port 0, loopback only) serves create_app on the real
instrument of an embedded simulated bench (``open_instrument(config/sim.toml, bench="embedded")``).
A scan is queued first (its chirp linearization, then the ROI), then ``clients`` concurrent
clients (asyncio + httpx, one connection each) each send ``requests_per_client`` requests, picked
by a seeded RNG among ``GET /health``, ``GET /scans`` and ``GET /scans/{id}``. Every request is
counted: an error is a transport failure or any status other than 200. Latency is measured per
request on the client side (perf_counter around the request).

Caveat, stated so the figures are read right: the clients, the server and the embedded bench (the
synthesis of the beat signals, the DSP) share one Python process and its GIL, so the latency
includes waiting for the scan's own compute; a daemon on the child-process bench (the default,
``sim.bench = "child"``) carries less of it.

    python benchmarks/load.py [--clients 50] [--requests 40] [--seed 1]

``run_load(...)`` returns the figures as a dict (used by ``python -m benchmarks``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import socket
import tempfile
import threading
import time
from collections import Counter
from contextlib import contextmanager

import numpy as np

from lidard.api.app import WorkerOptions, create_app
from lidard.config import CONFIG_DIR, load_config

# A full frame: long enough (linearization, then 96 x 128 pixels) to run through the whole load;
# it is cancelled afterwards (partial points kept) unless finish="wait".
DEFAULT_SCAN = {"pattern": "raster", "averages": 1, "max_range_m": 2.0, "formats": ["ply"]}
DEFAULT_SCENE = str(CONFIG_DIR / "scenes" / "cal_letters.toml")


@contextmanager
def serve(app, *, join_timeout_s: float = 30.0):
    """Run ``app`` on a uvicorn server bound to 127.0.0.1 on a free port; yields its base URL."""
    import uvicorn
    # IPPROTO_TCP, as lidard.cli.daemon.bind: with proto 0 asyncio skips TCP_NODELAY (+40 ms a response)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.bind(("127.0.0.1", 0))
    # backlog for the burst of connections the clients open at once
    server = uvicorn.Server(uvicorn.Config(app, log_level="error", lifespan="on", backlog=2048,
                                           timeout_graceful_shutdown=5))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True, name="uvicorn")
    thread.start()
    while not server.started:  # readiness without sleeping: the server thread sets the flag
        thread.join(0.01)
        if not thread.is_alive():
            raise RuntimeError("uvicorn exited before it started serving")
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}"
    finally:
        server.should_exit = True
        thread.join(join_timeout_s)
        sock.close()


async def _client(base_url: str, n: int, rng: random.Random, scan_id: str, start: asyncio.Event,
                  latencies_s: list[float], statuses: Counter, failures: list[str], per_path: Counter) -> None:
    import httpx
    paths = ["/health", "/scans", f"/scans/{scan_id}"]
    async with httpx.AsyncClient(base_url=base_url, timeout=60.0,
                                 limits=httpx.Limits(max_connections=1)) as http:
        await start.wait()
        for _ in range(n):
            k = rng.randrange(3)
            path = paths[k]
            per_path[("/health", "/scans", "/scans/{id}")[k]] += 1
            t = time.perf_counter()
            try:
                r = await http.get(path)
            except httpx.HTTPError as exc:
                latencies_s.append(time.perf_counter() - t)
                statuses["transport_error"] += 1
                failures.append(f"GET {path}: {type(exc).__name__}: {exc}")
                continue
            latencies_s.append(time.perf_counter() - t)
            statuses[r.status_code] += 1
            if r.status_code != 200:
                failures.append(f"GET {path}: {r.status_code} {r.text[:200]}")


async def _load(base_url: str, clients: int, requests_per_client: int, seed: int, scan_id: str):
    latencies: list[float] = []
    statuses: Counter = Counter()
    failures: list[str] = []
    per_path: Counter = Counter()
    start = asyncio.Event()
    tasks = [asyncio.create_task(_client(base_url, requests_per_client, random.Random(seed * 100_003 + i),
                                         scan_id, start, latencies, statuses, failures, per_path))
             for i in range(clients)]
    await asyncio.sleep(0)  # let every client open its client object before the start signal
    t0 = time.perf_counter()
    start.set()
    await asyncio.gather(*tasks)
    return latencies, statuses, failures, per_path, time.perf_counter() - t0


def run_load(clients: int = 50, requests_per_client: int = 40, seed: int = 1, *, instrument=None,
             cfg=None, scan: dict | None = None, scene: str = DEFAULT_SCENE,
             finish: str = "cancel", timeout_s: float = 600.0, bench: str = "embedded") -> dict:
    """Poll a live daemon from ``clients`` concurrent clients while a scan runs; return the figures.

    ``instrument``: the instrument to serve (default: the real one on an embedded simulated bench,
    closed afterwards). ``finish``: after the load, ``"cancel"`` the scan (DELETE; it keeps its
    points, partial) or ``"wait"`` up to ``timeout_s`` for it to end. ``bench``: where the
    simulated devices run when the instrument is built here (``"embedded"``: this process;
    ``"child"``: a ``lidar-sim`` child process, as the daemon runs by default).
    """
    if finish not in ("cancel", "wait"):
        raise ValueError(f"finish must be 'cancel' or 'wait', got {finish!r}")
    if clients < 1 or requests_per_client < 1:
        raise ValueError(f"clients and requests_per_client must be >= 1, got {clients}, {requests_per_client}")
    cfg = cfg if cfg is not None else load_config(CONFIG_DIR / "sim.toml")
    own = instrument is None
    if own:
        from lidard.instrument import open_instrument
        instrument = open_instrument(cfg, scene_path=scene, bench=bench)
    with tempfile.TemporaryDirectory(prefix="lidard-load-") as data_dir:
        app = create_app(cfg, instrument=instrument, data_dir=data_dir, close_instrument=own,
                         worker_options=WorkerOptions(progress_interval_s=0.25))
        with serve(app) as url:
            import httpx
            with httpx.Client(base_url=url, timeout=60.0) as http:
                r = http.post("/scans", json=scan or DEFAULT_SCAN)
                r.raise_for_status()
                scan_id = r.json()["id"]
                before = http.get(f"/scans/{scan_id}").json()
                latencies, statuses, failures, per_path, wall_s = asyncio.run(
                    _load(url, clients, requests_per_client, seed, scan_id))
                after = http.get(f"/scans/{scan_id}").json()
                if finish == "cancel" and after["state"] in ("queued", "running"):
                    http.delete(f"/scans/{scan_id}").raise_for_status()
            rec = app.state.worker.wait(scan_id, timeout_s)
            final = rec.state if rec is not None else None
    lat_ms = np.asarray(latencies) * 1e3
    n = int(sum(statuses.values()))
    return {
        "clients": clients, "requests_per_client": requests_per_client, "requests": n,
        "errors": n - int(statuses.get(200, 0)), "statuses": {str(k): v for k, v in sorted(statuses.items(), key=str)},
        "p50_ms": float(np.percentile(lat_ms, 50)), "p99_ms": float(np.percentile(lat_ms, 99)),
        "p999_ms": float(np.percentile(lat_ms, 99.9)), "max_ms": float(lat_ms.max()),
        "wall_s": wall_s, "requests_per_s": n / wall_s if wall_s > 0 else float("inf"),
        "scan_state": after["state"], "scan_stage": after["stage"], "scan_state_at_start": before["state"],
        "scan_stage_at_start": before["stage"], "scan_final_state": final,
        "per_path": dict(per_path), "first_failures": failures[:5], "seed": seed,
        "bench": bench if own else "given",
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--requests", type=int, default=40, help="requests per client")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--bench", choices=["embedded", "child"], default="embedded",
                    help="simulated devices in this process (default) or in a lidar-sim child process")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    res = run_load(args.clients, args.requests, args.seed, bench=args.bench)
    if args.json:
        print(json.dumps(res))
        return 0 if res["errors"] == 0 else 1
    print(f"{res['clients']} clients x {res['requests_per_client']} requests = {res['requests']} requests "
          f"in {res['wall_s']:.2f} s ({res['requests_per_s']:.0f} req/s) while a scan ran "
          f"(scan {res['scan_state_at_start']}/{res['scan_stage_at_start']} -> {res['scan_state']}/"
          f"{res['scan_stage']} during the load, "
          f"finally {res['scan_final_state']})")
    print(f"errors {res['errors']}  statuses {res['statuses']}")
    print(f"latency p50 {res['p50_ms']:.1f} ms  p99 {res['p99_ms']:.1f} ms  p99.9 {res['p999_ms']:.1f} ms  "
          f"max {res['max_ms']:.1f} ms")
    for f in res["first_failures"]:
        print(f"  {f}")
    return 0 if res["errors"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
