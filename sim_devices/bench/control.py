"""The control socket of a bench running as its own process (``lidar-sim --json``), and its client.

A JSON-lines protocol on 127.0.0.1: set_scene, set_interlock, advance, ground_truth, truth, ping,
inject, clear_faults, faults, fidelity (the ledger of modelled / skipped effects), heap (the bench
process's C heap and threads, for memory tests and soaks). The server side
calls the :class:`sim_devices.bench.bench.Bench` it serves; the client (:class:`BenchControlClient`) is
what lidard's composition root uses to steer a child bench.
"""

from __future__ import annotations

import json
import os
import socket
import threading

import numpy as np

from lidard import heap
from sim_devices.world.scene import Scene, SceneError


class _ControlServer:
    """JSON-lines control socket on 127.0.0.1 for a bench running as its own process.

    Every reply is ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``. Fault commands:
    ``{"cmd": "inject", "kind": K, **params}`` -> ``{"fault": {...}}``,
    ``{"cmd": "clear_faults", "kind": K | null}`` -> ``{"cleared": n}``,
    ``{"cmd": "faults"}`` -> ``{"faults": [...]}``. Tests and benchmarks only:
    ``{"cmd": "truth"}`` -> ``{"truth": BenchTruth.as_dict()}`` (the hidden tolerances);
    ``{"cmd": "heap"}`` -> ``{"heap": lidard.heap.usage() (None without glibc), "threads": [names of
    the Python threads], "os_threads": n, "anon_bytes": resident anonymous memory (None without
    procfs), "trims": lidard.heap.trims_done()}`` (what a long-running bench process holds).
    """

    def __init__(self, bench) -> None:   # a sim_devices.bench.bench.Bench (not imported: no cycle)
        self.bench = bench
        self._sock = socket.create_server(("127.0.0.1", 0))
        self.port = self._sock.getsockname()[1]
        self._closed = False
        self._thread = threading.Thread(target=self._serve, name="bench-control", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._closed:
            try:
                conn, _ = self._sock.accept()
            except OSError:
                return
            threading.Thread(target=self._client, args=(conn,), daemon=True).start()

    def _client(self, conn: socket.socket) -> None:
        with conn, conn.makefile("rwb") as f:
            for line in f:
                try:
                    reply = {"ok": True, **self.handle(json.loads(line))}
                except (SceneError, ValueError, KeyError, TypeError) as exc:
                    reply = {"ok": False, "error": str(exc)}
                f.write((json.dumps(reply) + "\n").encode())
                f.flush()

    def handle(self, msg: dict) -> dict:
        b = self.bench
        cmd = msg.get("cmd")
        if cmd == "ping":
            return {"t_s": b.clock.now()}
        if cmd == "advance":
            return {"t_s": b.clock.advance(float(msg["dt_s"]))}
        if cmd == "set_scene":
            scene = Scene.from_dict(msg["scene"], source="<control>")
            b.set_scene(scene)
            return {"name": scene.name, "targets": len(scene)}
        if cmd == "hold_scene_clock":
            b.hold_scene_clock(bool(msg["hold"]))
            return {}
        if cmd == "set_interlock":
            b.controller.set_interlock(bool(msg["closed"]))
            return {}
        if cmd == "inject":
            params = {k: v for k, v in msg.items() if k not in ("cmd", "kind")}
            return {"fault": b.inject_fault(msg.get("kind"), **params)}
        if cmd == "clear_faults":
            return {"cleared": b.clear_faults(msg.get("kind"))}
        if cmd == "faults":
            return {"faults": b.active_faults()}
        if cmd == "fidelity":
            return {"fidelity": b.fidelity.snapshot()}
        if cmd == "truth":   # the hidden tolerances, for tests/benchmarks of a child bench
            return {"truth": b.truth().as_dict()}
        if cmd == "heap":    # the process's memory and threads, for memory tests and soaks
            return {"heap": heap.usage(), "threads": sorted(t.name for t in threading.enumerate()),
                    "os_threads": _os_threads(), "anon_bytes": _anon_bytes(),
                    "trims": heap.trims_done()}
        if cmd == "ground_truth":
            truth = b.ground_truth(np.asarray(msg["rows"]), np.asarray(msg["cols"]))
            return {"range_m": [None if not np.isfinite(x) else float(x) for x in truth]}
        raise ValueError(f"unknown control command {cmd!r}")

    def close(self) -> None:
        self._closed = True
        self._sock.close()


def _anon_bytes() -> int | None:
    """Resident anonymous memory of this process (the heaps, the mappings of large blocks), bytes;
    None without procfs."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("RssAnon:"):
                    return int(line.split()[1]) << 10
    except OSError:
        pass
    return None


def _os_threads() -> int:
    """Threads of this process, the interpreter's own and those of native libraries alike."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:                       # no procfs: the Python threads only
        return threading.active_count()


class BenchControlClient:
    """Client of a child bench's control socket (used by the composition root of lidard)."""

    def __init__(self, port: int, host: str = "127.0.0.1") -> None:
        self._sock = socket.create_connection((host, port), timeout=10)
        self._f = self._sock.makefile("rwb")
        self._lock = threading.Lock()

    def call(self, cmd: str, **kw) -> dict:
        with self._lock:
            self._f.write((json.dumps({"cmd": cmd, **kw}) + "\n").encode())
            self._f.flush()
            line = self._f.readline()
        if not line:
            raise ConnectionError("simulated bench closed its control socket")
        reply = json.loads(line)
        if not reply.pop("ok"):
            raise ValueError(reply.get("error", "bench control error"))
        return reply

    def close(self) -> None:
        self._f.close()
        self._sock.close()
