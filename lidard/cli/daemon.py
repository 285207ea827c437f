"""``lidard``: the daemon's entry point. Loads the configuration, binds the port before any hardware
is touched (a busy port is one clear line), builds the instrument through the composition root and
serves the FastAPI app (lidard.api.app.create_app) with uvicorn. Refuses a non-loopback address
without an API token.

Shutdown (SIGTERM or Ctrl-C): the running scan is stopped first (its points kept, state
``interrupted``, the signal named as its stop reason) while connections are still open, so every
client following it gets its ``end`` event with the final record; then uvicorn closes connections
and the lifespan powers the bench down. A shutdown that completed exits 0: the signal asked for it
(uvicorn would re-raise it after a graceful exit, and the process would end "killed by SIGTERM")."""

from __future__ import annotations

import argparse
import ipaddress
import os
import threading
import sys

from . import base
from .base import CliError, Parser, run


def is_loopback(host: str) -> bool:
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="lidard", description="FPSA FMCW LiDAR control daemon (REST API, OpenAPI at /docs).",
               formatter_class=base.HelpFormatter)
    p.add_argument("--config", default=None, metavar="FILE.toml",
                   help="configuration TOML, e.g. config/sim.toml (default search path)")
    p.add_argument("--host", default=None, help="bind address (default from config: 127.0.0.1)")
    p.add_argument("--port", type=int, default=None, help="TCP port, 0..65535 (default from config: 8470)")
    p.add_argument("--data-dir", default=None, metavar="DIR", help="store directory (default from config)")
    p.add_argument("--token", default=None, help="API token (default $LIDARD_API_TOKEN); "
                                                 "required to bind a non-loopback address")
    p.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"],
                   help="log verbosity")
    p.add_argument("--foxglove", action="store_true",
                   help="also serve the Foxglove live stream (as [live] foxglove = true; loopback, port from "
                        "[live] foxglove_port, default 8765)")
    return p


def _load_dsp_kernels() -> None:
    # the DSP pool's warm-up (the compiled kernels loaded, the frame DSP run once on a made-up batch),
    # the same one its forkserver runs; a failure there only leaves the kernels to load later
    import importlib
    importlib.import_module("lidard.dsp_pool_preload")


def serve(args) -> int:
    # before any thread exists: a daemon's heap must not creep up over weeks of scans (lidard.heap)
    from .. import heap
    heap.configure()
    cfg = base.load_config(args.config)
    if args.foxglove:
        cfg = cfg.model_copy(update={"live": cfg.live.model_copy(update={"foxglove": True})})
    host = args.host or cfg.daemon.host
    port = cfg.daemon.port if args.port is None else args.port
    if not 0 <= port <= 65535:
        raise CliError(f"--port must be in 0..65535, got {port}")
    token = args.token or os.environ.get("LIDARD_API_TOKEN") or None
    if not is_loopback(host) and not token:
        raise CliError(f"refusing to bind non-loopback address {host}: set an API token "
                       "(--token or LIDARD_API_TOKEN) first")
    data_dir = args.data_dir or cfg.daemon.data_dir
    # Bind before starting the bench or the hardware: a busy port is then one clear line.
    sock = bind(host, port)
    import uvicorn

    from ..api.app import ApiAccess, WorkerOptions, create_app
    from ..store import Store
    try:
        # the data directory's lock before the bench or the hardware: a second daemon on a held
        # directory exits at once, naming the holder's PID
        store = Store(data_dir)
    except BaseException:
        sock.close()
        raise
    try:
        instrument = base.open_instrument(cfg)
    except BaseException:
        sock.close()
        store.close()
        raise
    # the daemon opened its bench from the configuration: it calibrates itself at its first scan when
    # sim.factory_calibration is on (create_app checks that it is a simulated bench)
    app = create_app(cfg, instrument=instrument, store=store, access=ApiAccess(token=token),
                     worker_options=WorkerOptions(factory_calibration=cfg.sim.factory_calibration))
    # The frame DSP's compiled kernels, loaded now beside the start-up: a one-batch scan's DSP runs in
    # this process, and a daemon passes the kernels' break-even (lidard.dsp.spectrum.jit.LOAD_AFTER_CELLS)
    # within the hour of small scans; loaded then, numba's libraries and code generator came as one
    # ~110 MB jump of the daemon's memory 50 minutes into a soak. Loaded at start, the daemon is at its
    # steady size from its first minutes (docs/reliability.md). LIDARD_DSP_JIT=0 loads nothing.
    threading.Thread(target=_load_dsp_kernels, name="lidard-dsp-kernels", daemon=True).start()
    # an open event stream must not hold shutdown (and the laser/HV power-down) hostage
    server = _server_class()(uvicorn.Config(app, log_level=args.log_level, timeout_graceful_shutdown=5), app)
    sys.stderr.write(f"lidard: serving on http://{host}:{sock.getsockname()[1]} (OpenAPI at /docs)\n")
    if not is_loopback(host):
        # the daemon speaks plain HTTP: the bearer token crosses the network in clear text
        sys.stderr.write("lidard: warning: plain HTTP on a non-loopback address; the API token is sent in "
                         "clear text, so put a TLS proxy or an SSH tunnel in front for untrusted networks\n")
    server.run(sockets=[sock])
    return 0


def _server_class():
    import asyncio
    import contextlib
    import signal

    import uvicorn

    class Server(uvicorn.Server):
        """uvicorn's server, with the scan stopped before connections close and no re-raised signal."""

        def __init__(self, config, app):
            super().__init__(config)
            self.app = app

        async def shutdown(self, sockets=None) -> None:
            worker = getattr(self.app.state, "worker", None)
            if worker is not None:
                sigs = [signal.Signals(s).name for s in self._captured_signals]
                reason = f"lidard shut down ({', '.join(sigs) or 'stopped'})"
                # on a thread: the event loop keeps serving the scan's event streams meanwhile
                await asyncio.to_thread(worker.stop, reason=reason)
            await super().shutdown(sockets)

        @contextlib.contextmanager
        def capture_signals(self):
            with super().capture_signals():
                yield
                # reached only when serving ended without an exception: a clean shutdown
                self._captured_signals.clear()

    return Server


def bind(host: str, port: int):
    import socket
    family = socket.AF_INET6 if ":" in host.strip("[]") else socket.AF_INET
    # proto must say TCP: asyncio sets TCP_NODELAY on accepted connections only when the socket's
    # proto is IPPROTO_TCP, and with proto 0 Nagle + delayed ACK add ~40 ms to every response
    # (measured: 46 ms -> 0.8 ms per sequential request, benchmarks/load.py).
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host.strip("[]"), port))
        # listen now: a client that connects once "serving on" is printed waits in the backlog
        # until the app has started instead of being refused
        sock.listen(2048)
    except OSError as exc:
        sock.close()
        raise CliError(f"cannot bind {host}:{port}: {exc.strerror or exc}") from None
    sock.set_inheritable(True)
    return sock


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run(serve, args, "lidard")
