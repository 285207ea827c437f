"""Issue 6 security: loopback default, token only for mutating requests, request body limits.

The non-loopback refusal is checked on the real entry point in a child process (``python -m
lidard``), because what matters is the exit status and the one line a user sees.
"""

import asyncio
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lidard.api.control import BodySizeLimit, token_ok
from lidard.cli import build_lidard_parser, is_loopback
from lidard.config import Config, ConfigError, load_config
from tests.helpers.api import app_client, make_app
from tests.helpers.fakes import FakeInstrument

SMALL = {"pattern": "roi", "rows": [0, 3], "cols": [0, 20]}
SCENE = 'name = "wall"\n[[target]]\nkind = "plane"\npoint = [0.0, 0.0, 2.0]\nnormal = [0.0, 0.0, -1.0]\n'
AUTH = {"Authorization": "Bearer s3cret"}


@pytest.fixture
def app_with_token(tmp_path):
    inst = FakeInstrument()
    with app_client(tmp_path, inst, token="s3cret", max_body_bytes=4096) as c:
        yield c, inst, c.app


def test_default_bind_is_loopback():
    assert Config().daemon.host == "127.0.0.1"
    assert build_lidard_parser().parse_args([]).host is None  # so the config default applies
    assert load_config().daemon.host == "127.0.0.1"
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5") and not is_loopback("::")


def _run_lidard(*args, env_extra=None):
    env = {k: v for k, v in os.environ.items() if k not in ("LIDARD_API_TOKEN", "LIDARD_DEBUG")}
    env.update(env_extra or {})
    return subprocess.run([sys.executable, "-m", "lidard", *args], capture_output=True, text=True,
                          timeout=60, env=env, stdin=subprocess.DEVNULL)


def test_non_loopback_bind_without_token_exits_nonzero_with_one_clear_line(tmp_path):
    r = _run_lidard("--host", "0.0.0.0", "--port", "0", "--data-dir", str(tmp_path))
    assert r.returncode != 0
    err = r.stderr.strip().splitlines()
    assert len(err) == 1, r.stderr
    assert "refusing to bind non-loopback address 0.0.0.0" in err[0]
    assert "--token" in err[0] and "LIDARD_API_TOKEN" in err[0]
    assert "serving" not in r.stderr and r.stdout == ""
    # an empty token is no token
    r = _run_lidard("--host", "0.0.0.0", "--port", "0", "--data-dir", str(tmp_path),
                    env_extra={"LIDARD_API_TOKEN": ""})
    assert r.returncode != 0 and "refusing to bind" in r.stderr


def test_token_compare_is_exact():
    assert token_ok("abc", "Bearer abc")
    for bad in (None, "", "Bearer ab", "Bearer abcd", "bearer abc", "abc", "Bearer  abc"):
        assert not token_ok("abc", bad), bad


def test_reads_open_mutations_need_the_token(app_with_token):
    c, inst, app = app_with_token
    for path in ("/health", "/devices", "/scanner", "/scans", "/control", "/openapi.json"):
        assert c.get(path).status_code == 200, path
    mutations = [("POST", "/scans", {"json": SMALL}), ("POST", "/calibration/linearize", {}),
                 ("PUT", "/sim/scene", {"content": SCENE, "headers": {"content-type": "application/toml"}}),
                 ("DELETE", "/scans/NOPE", {}), ("POST", "/control", {"json": {"client": "x"}}),
                 ("DELETE", "/control", {})]
    for method, path, kw in mutations:
        for bad in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": "s3cret"}):
            kw2 = dict(kw)
            kw2["headers"] = {**kw.get("headers", {}), **bad}
            r = c.request(method, path, **kw2)
            assert r.status_code == 401, (method, path, bad)
            assert r.headers["www-authenticate"] == "Bearer"
            assert "Bearer" in r.json()["detail"]
    # nothing reached the instrument or the store
    assert inst.requests == [] and inst.scenes == [] and inst.linearize_calls == 0
    assert c.get("/scans").json()["scans"] == []
    # with the token they are served
    assert c.post("/scans", json=SMALL, headers=AUTH).status_code == 201
    assert c.put("/sim/scene", content=SCENE, headers={**AUTH, "content-type": "application/toml"}).status_code == 200
    assert c.delete("/scans/NOPE", headers=AUTH).status_code == 404


def test_declared_content_length_over_limit_is_413_before_reading(app_with_token):
    c, inst, app = app_with_token
    big = "# " + "x" * 5000 + "\n" + SCENE
    r = c.put("/sim/scene", content=big, headers={**AUTH, "content-type": "application/toml"})
    assert r.status_code == 413 and "4096" in r.json()["detail"]
    assert inst.scenes == []
    # just under the limit passes
    ok = "# " + "x" * (4096 - len(SCENE) - 10) + "\n" + SCENE
    assert len(ok.encode()) <= 4096
    r = c.put("/sim/scene", content=ok, headers={**AUTH, "content-type": "application/toml"})
    assert r.status_code == 200 and len(inst.scenes) == 1


def test_streamed_body_over_limit_is_413(app_with_token):
    """A chunked body (no Content-Length) is counted as it arrives."""
    c, inst, app = app_with_token

    def chunks():
        yield SCENE.encode()
        for _ in range(10):
            yield b"# " + b"y" * 1000 + b"\n"
    r = c.put("/sim/scene", content=chunks(), headers={**AUTH, "content-type": "application/toml"})
    assert "content-length" not in {k.lower() for k in r.request.headers}
    assert r.status_code == 413 and inst.scenes == []
    r = c.post("/scans", content=chunks(), headers={**AUTH, "content-type": "application/json"})
    assert r.status_code == 413 and inst.requests == []


def _asgi_call(mw, headers, chunks):
    """Drive the middleware by hand: returns (status, app_saw_bytes)."""
    sent = []
    seen = bytearray()

    async def app(scope, receive, send):
        while True:
            m = await receive()
            seen.extend(m.get("body", b""))
            if not m.get("more_body"):
                break
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"ok"})

    msgs = [{"type": "http.request", "body": ch, "more_body": i < len(chunks) - 1} for i, ch in enumerate(chunks)]

    async def receive():
        return msgs.pop(0)

    async def send(m):
        sent.append(m)

    scope = {"type": "http", "method": "POST", "path": "/x", "headers": headers}
    asyncio.run(BodySizeLimit(app, max_body_bytes=10)(scope, receive, send) if mw is None else mw)
    return sent[0]["status"], bytes(seen)


def test_body_limit_middleware_lying_content_length_and_bad_header():
    # declares 5 bytes but streams 12: counted, refused
    status, _ = _asgi_call(None, [(b"content-length", b"5")], [b"123456", b"789012"])
    assert status == 413
    status, seen = _asgi_call(None, [(b"content-length", b"10")], [b"12345", b"67890"])
    assert status == 200 and seen == b"1234567890"
    status, seen = _asgi_call(None, [(b"content-length", b"11")], [b"12345678901"])
    assert status == 413 and seen == b""
    status, _ = _asgi_call(None, [(b"content-length", b"abc")], [b""])
    assert status == 400
    with pytest.raises(ValueError, match="max_body_bytes"):
        BodySizeLimit(None, max_body_bytes=0)


def test_max_body_bytes_comes_from_config(tmp_path):
    cfg = Config.model_validate({**load_config().model_dump(), "daemon": {"max_body_bytes": 2048}})
    with app_client(tmp_path, cfg=cfg) as c:
        r = c.put("/sim/scene", content="#" * 3000, headers={"content-type": "application/toml"})
        assert r.status_code == 413 and "2048" in r.json()["detail"]
    bad = tmp_path / "bad.toml"
    bad.write_text("[daemon]\nmax_body_bytes = 0\n")
    with pytest.raises(ConfigError, match="max_body_bytes"):
        load_config(bad)


# -- the same limits on a live uvicorn server, with raw sockets (what a hostile client would send)
def _live(tmp_path, **kw):
    from benchmarks.load import serve
    inst = FakeInstrument()
    app = make_app(tmp_path, inst, max_body_bytes=4096, **kw)
    return serve(app), inst


def _raw_http(url, head: bytes, body_chunks=()) -> tuple[int, bytes]:
    import socket
    host, port = url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=20) as s:
        s.sendall(head)
        for ch in body_chunks:
            try:
                s.sendall(ch)
            except OSError:  # the server may close as soon as it has answered 413
                break
        data = b""
        while True:  # headers, then exactly Content-Length bytes of body (or until the server closes)
            if b"\r\n\r\n" in data:
                head_part, body = data.split(b"\r\n\r\n", 1)
                length = [int(h.split(b":")[1]) for h in head_part.lower().split(b"\r\n")
                          if h.startswith(b"content-length:")]
                if length and len(body) >= length[0]:
                    break
            got = s.recv(65536)
            if not got:
                break
            data += got
    status = int(data.split(b" ", 2)[1])
    return status, data


def test_live_declared_length_over_limit_is_answered_without_waiting_for_the_body(tmp_path):
    server, inst = _live(tmp_path)
    with server as url:
        # 100 MB announced, not one body byte sent: the answer must come anyway (no read, no wait)
        head = (b"PUT /sim/scene HTTP/1.1\r\nHost: x\r\nContent-Type: application/toml\r\n"
                b"Content-Length: 100000000\r\n\r\n")
        status, data = _raw_http(url, head)
        assert status == 413 and b"4096" in data
    assert inst.scenes == []


def test_live_chunked_body_over_limit_is_413(tmp_path):
    server, inst = _live(tmp_path)
    with server as url:
        head = (b"PUT /sim/scene HTTP/1.1\r\nHost: x\r\nContent-Type: application/toml\r\n"
                b"Transfer-Encoding: chunked\r\n\r\n")
        piece = b"# " + b"z" * 1021 + b"\n"  # 1 KiB of TOML comment per chunk
        chunks = [b"%x\r\n%s\r\n" % (len(piece), piece) for _ in range(8)] + [b"0\r\n\r\n"]
        status, _ = _raw_http(url, head, chunks)
        assert status == 413
        # under the limit, chunked, is served
        small = SCENE.encode()
        status, _ = _raw_http(url, head, [b"%x\r\n%s\r\n" % (len(small), small), b"0\r\n\r\n"])
        assert status == 200
    assert len(inst.scenes) == 1


@pytest.mark.slow  # a real daemon process and its child bench
def test_real_daemon_with_token_on_all_interfaces_reads_open_writes_need_token(tmp_path):
    """`python -m lidard --host 0.0.0.0 --token T` on the simulated bench: serves, warns about plain
    HTTP, GET is open, POST without the token is 401 and with it 201."""
    import threading

    import httpx
    env = {k: v for k, v in os.environ.items() if k not in ("LIDARD_API_TOKEN", "LIDARD_DEBUG")}
    env["LIDARD__SIM__BENCH"] = "embedded"  # no child process to start: quicker, same API
    cfg = Path(__file__).resolve().parents[2] / "config" / "sim.toml"
    proc = subprocess.Popen([sys.executable, "-m", "lidard", "--config", str(cfg), "--host", "0.0.0.0",
                             "--port", "0", "--token", "T0ken", "--data-dir", str(tmp_path / "data"),
                             "--log-level", "warning"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, env=env)
    watchdog = threading.Timer(120.0, proc.kill)  # a hung daemon fails the test instead of hanging it
    watchdog.start()
    try:
        lines = []
        while not any("serving on" in ln for ln in lines):
            ln = proc.stderr.readline()
            assert ln, f"lidard exited: {''.join(lines)}"
            lines.append(ln)
        port = int(lines[-1].split("0.0.0.0:")[1].split()[0])
        warning = proc.stderr.readline()
        assert "clear text" in warning and "TLS" in warning
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30) as c:
            assert c.get("/health").status_code == 200
            assert c.get("/control").json()["held"] is False
            assert c.post("/scans", json=SMALL).status_code == 401
            assert c.post("/control", json={"client": "x"}, headers={"Authorization": "Bearer nope"}).status_code == 401
            r = c.post("/scans", json={**SMALL, "formats": ["npz"]}, headers={"Authorization": "Bearer T0ken"})
            assert r.status_code == 201
            assert c.delete(f"/scans/{r.json()['id']}", headers={"Authorization": "Bearer T0ken"}).status_code == 200
    finally:
        watchdog.cancel()
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    assert proc.returncode is not None


def test_daemon_socket_gets_tcp_nodelay_on_every_connection():
    """lidard binds its own socket; asyncio turns Nagle off on accepted connections only for a
    socket whose proto is TCP (with proto 0 every response waited ~40 ms for a delayed ACK)."""
    import socket

    from lidard.cli.daemon import bind
    sock = bind("127.0.0.1", 0)
    assert sock.proto == socket.IPPROTO_TCP
    seen = []

    class Probe(asyncio.Protocol):
        def connection_made(self, transport):
            seen.append(transport.get_extra_info("socket").getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))
            transport.close()

    async def main():
        server = await asyncio.get_running_loop().create_server(Probe, sock=sock)
        async with server:
            _, writer = await asyncio.open_connection("127.0.0.1", sock.getsockname()[1])
            while not seen:
                await asyncio.sleep(0)
            writer.close()
    asyncio.run(asyncio.wait_for(main(), 20))
    assert len(seen) == 1 and seen[0] != 0


@pytest.mark.parametrize("origin, host, token_set, refused", [
    (None, "127.0.0.1:8470", False, False),                          # lidarctl, curl: no Origin
    ("http://127.0.0.1:8470", "127.0.0.1:8470", False, False),       # the daemon's own /docs page
    ("http://localhost:8470", "localhost:8470", False, False),
    ("http://[::1]:8470", "[::1]:8470", False, False),
    ("https://evil.example", "127.0.0.1:8470", False, True),         # classic CSRF
    ("https://evil.example", "127.0.0.1:8470", True, True),
    ("null", "127.0.0.1:8470", False, True),                         # sandboxed iframe / file://
    ("http://evil.example:8470", "evil.example:8470", False, True),  # DNS rebinding, no token
    ("http://labpc:8470", "labpc:8470", True, False),                # same-origin page, token set
    ("http://127.0.0.1:9999", "127.0.0.1:8470", False, True),        # another port is another origin
])
def test_cross_origin_rule(origin, host, token_set, refused):
    from lidard.api.control import cross_origin_refusal
    why = cross_origin_refusal(origin, host, token_set)
    assert (why is not None) == refused, why
    if refused:
        assert "refused" in why


def test_web_page_cannot_steer_a_loopback_daemon(tmp_path):
    """A 'simple' cross-origin POST (no preflight) must not start a linearization (laser on)."""
    inst = FakeInstrument()
    with app_client(tmp_path, inst, client_kw={"base_url": "http://127.0.0.1:8470"}) as c:
        r = c.post("/calibration/linearize", headers={"Origin": "https://evil.example"})
        assert r.status_code == 403 and "evil.example" in r.json()["detail"]
        r = c.post("/scans", content=json.dumps(SMALL), headers={"Origin": "https://evil.example",
                                                                  "content-type": "text/plain"})
        assert r.status_code == 403
        assert inst.linearize_calls == 0 and inst.requests == []
        # reads are not refused (no side effects; the browser's same-origin policy hides the answer)
        assert c.get("/health", headers={"Origin": "https://evil.example"}).status_code == 200
        # the daemon's own page and command-line clients steer as before
        assert c.post("/scans", json=SMALL, headers={"Origin": "http://127.0.0.1:8470"}).status_code == 201
        assert c.post("/scans", json=SMALL).status_code == 201
