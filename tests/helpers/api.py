"""The daemon's FastAPI app for tests: in process through Starlette's TestClient (lifespan run, so
store and worker start and stop), or on a live uvicorn server on a free loopback port for clients
that need a real socket (lidarctl, raw HTTP). Readiness is awaited by joining the server thread with
a timeout, never by sleeping."""

from __future__ import annotations

import contextlib
import dataclasses
import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient

from lidard.api.app import ApiAccess, WorkerOptions, create_app
from lidard.config import load_config
from tests.helpers.fakes import FakeInstrument


def make_app(data_dir: str | Path, instrument: Any = None, cfg: Any = None, **app_kw):
    """``create_app`` with the default configuration and a :class:`FakeInstrument` unless given;
    ``app_kw``: its keywords, or a field of its :class:`ApiAccess` or :class:`WorkerOptions` by name."""
    inst = FakeInstrument() if instrument is None else instrument
    access = {k: app_kw.pop(k) for k in [f.name for f in dataclasses.fields(ApiAccess)] if k in app_kw}
    worker = {k: app_kw.pop(k) for k in [f.name for f in dataclasses.fields(WorkerOptions)] if k in app_kw}
    return create_app(load_config() if cfg is None else cfg, instrument=inst, data_dir=data_dir,
                      access=ApiAccess(**access), worker_options=WorkerOptions(**worker), **app_kw)


@contextlib.contextmanager
def app_client(data_dir: str | Path, instrument: Any = None, cfg: Any = None,
               client_kw: dict[str, Any] | None = None, **app_kw) -> Iterator[TestClient]:
    """An entered TestClient on :func:`make_app` (lifespan started; stopped on exit)."""
    with TestClient(make_app(data_dir, instrument, cfg, **app_kw), **(client_kw or {})) as c:
        yield c


@contextlib.contextmanager
def live_server(app) -> Iterator[str]:
    """Serve ``app`` with uvicorn on 127.0.0.1:<free port>; yield its URL; stop and join on exit."""
    import uvicorn
    # IPPROTO_TCP so that asyncio sets TCP_NODELAY on accepted connections (see lidard.cli.daemon.bind)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, log_level="error", lifespan="on"))
    t = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    t.start()
    try:
        for _ in range(1000):
            if server.started:
                break
            t.join(0.01)
        assert server.started, "uvicorn did not start within 10 s"
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        t.join(10)
        sock.close()
    assert not t.is_alive(), "uvicorn did not stop within 10 s"
