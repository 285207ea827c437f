"""Streams through a REAL daemon (python -m lidard on config/sim.toml with its child bench): a stream's
frames reach a client while it runs, DELETE stops it keeping the frames, an MCAP stream holds one
message per frame."""

from __future__ import annotations

import io

import httpx
import numpy as np
import pytest
from plyfile import PlyData

from lidard.outputs.mcap import read_mcap
from tests.helpers.daemon import poll, start_daemon, stop_daemon
from tests.helpers.deadlines import HTTP_S, WAIT_S

pytestmark = pytest.mark.slow

BODY = {"pattern": "roi", "rows": [48, 64], "cols": [48, 64], "max_range_m": 2.0}   # 192 bonded pixels


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    proc, url = start_daemon(tmp_path_factory.mktemp("stream-data"))
    yield url
    stop_daemon(proc)


def _get(url: str) -> dict:
    r = httpx.get(url, timeout=HTTP_S)
    assert r.status_code == 200, r.text
    return r.json()


def test_mcap_stream_has_one_message_per_frame(daemon, tmp_path):
    r = httpx.post(daemon + "/streams", json={**BODY, "frames": 3, "format": "mcap"}, timeout=HTTP_S)
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    st = poll(lambda: (s := _get(f"{daemon}/streams/{sid}"))["state"] in ("done", "stopped", "failed") and s,
              300, "stream to end")
    assert st["state"] == "done" and st["frames_done"] == 3, st
    m = httpx.get(f"{daemon}/streams/{sid}/mcap", timeout=HTTP_S)
    assert m.status_code == 200
    (tmp_path / "s.mcap").write_bytes(m.content)
    pts, statuses = read_mcap(tmp_path / "s.mcap")
    assert [s["frame"] for s in statuses] == [0, 1, 2]
    assert [s["pixels_scanned"] for s in statuses] == [192, 192, 192]
    assert sorted(set(pts["frame"].tolist())) == [0, 1, 2]
    # every frame's points lie inside its own trigger span, counted from the stream's first trigger
    for s in statuses:
        t = pts["t"][pts["frame"] == s["frame"]]
        assert t.min() >= s["start_s"] - 1e-9 and t.max() <= s["start_s"] + s["hardware_time_s"]


def test_frames_reach_the_client_and_delete_keeps_them(daemon):
    r = httpx.post(daemon + "/streams", json=BODY, timeout=HTTP_S)       # no frames: until stopped
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    live = poll(lambda: (s := _get(f"{daemon}/streams/{sid}"))["frames_done"] >= 2 and s, WAIT_S, "two frames")
    assert live["state"] == "running"
    assert [f["frame"] for f in live["frames"][:2]] == [0, 1]
    d = httpx.delete(f"{daemon}/streams/{sid}", timeout=HTTP_S)
    assert d.status_code == 200
    end = poll(lambda: (s := _get(f"{daemon}/streams/{sid}"))["state"] != "running" and s, WAIT_S, "stream to stop")
    assert end["state"] == "stopped" and end["frames_done"] >= 2
    for k in range(end["frames_done"]):
        f = httpx.get(f"{daemon}/streams/{sid}/frames/{k}", timeout=HTTP_S)
        assert f.status_code == 200
        v = PlyData.read(io.BytesIO(f.content))["vertex"].data
        assert set(np.unique(v["frame"]).tolist()) <= {k}
    assert len(PlyData.read(io.BytesIO(httpx.get(f"{daemon}/streams/{sid}/frames/0").content))["vertex"].data) > 0
    assert httpx.get(f"{daemon}/streams/nope", timeout=HTTP_S).status_code == 404
    bad = httpx.post(daemon + "/streams", json={**BODY, "pattern": "raster", "frame_rate_hz": 10}, timeout=HTTP_S)
    assert bad.status_code == 422 and "frame_rate_hz" in bad.text


def _lidarctl(*args: str, **kw):
    import os
    import subprocess
    import sys
    return subprocess.Popen([sys.executable, "-c", "import sys; from lidard.cli.lidarctl import main; sys.exit(main())", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env={**os.environ, "PYTHONUNBUFFERED": "1"}, **kw)


def test_lidarctl_stream_writes_frames_and_sigterm_keeps_them(daemon, tmp_path):
    import json
    import signal
    p = _lidarctl("stream", "--url", daemon, "--pattern", "roi", "--rows", "48:64", "--cols", "48:64",
                  "--frames", "2", "--out", str(tmp_path / "frames") + "/")
    out, err = p.communicate(timeout=WAIT_S)
    assert p.returncode == 0, err.decode()
    files = sorted(x.name for x in (tmp_path / "frames").iterdir())
    assert files == ["frame_00000.ply", "frame_00000.ply.json", "frame_00001.ply", "frame_00001.ply.json"]
    assert json.loads((tmp_path / "frames" / "frame_00001.ply.json").read_text())["frame"] == 1
    # until stopped: SIGTERM after the second frame is reported stops the stream and keeps its frames
    p = _lidarctl("stream", "--url", daemon, "--pattern", "roi", "--rows", "48:64", "--cols", "48:64",
                  "--out", str(tmp_path / "more") + "/")
    lines = []
    for raw in p.stderr:
        lines.append(raw.decode())
        if raw.startswith(b"frame 1:"):
            p.send_signal(signal.SIGTERM)
            break
    out, err = p.communicate(timeout=WAIT_S)
    assert p.returncode == 128 + signal.SIGTERM, "".join(lines) + err.decode()   # 143: stopped by SIGTERM
    kept = sorted(x.name for x in (tmp_path / "more").iterdir() if x.suffix == ".ply")
    assert len(kept) >= 2 and kept[:2] == ["frame_00000.ply", "frame_00001.ply"]


def test_foxglove_client_gets_each_frame_live_from_a_real_daemon(tmp_path):
    """The daemon with its Foxglove live server on: a WebSocket client subscribed before the stream
    starts gets one PointCloud per frame, in frame order, each with only that frame's points and as
    many as the frame's sidecar counts, each followed by its frame event, then the stream's end."""
    import json
    import socket
    import struct

    from websockets.sync.client import connect

    from lidard.outputs.channels import POINTS_TOPIC, STATUS_TOPIC
    from lidard.outputs.mcap import decode_point_cloud

    with socket.socket() as s:          # a free loopback port for the live server
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc, url = start_daemon(tmp_path / "data", env={"LIDARD__LIVE__FOXGLOVE": "true",
                                                     "LIDARD__LIVE__FOXGLOVE_PORT": str(port)})
    n, seen = 3, []
    try:
        with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
                     open_timeout=30) as ws:
            while True:
                msg = json.loads(ws.recv(timeout=30))
                if msg.get("op") == "advertise":
                    channels = {ch["topic"]: ch for ch in msg["channels"]}
                    break
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 1, "channelId": channels[POINTS_TOPIC]["id"]},
                {"id": 2, "channelId": channels[STATUS_TOPIC]["id"]}]}))
            # the subscription is in once the server's devices/status traffic reaches us; the stream's
            # own messages come after its linearization anyway (tens of seconds on the sim bench)
            r = httpx.post(url + "/streams", json={**BODY, "frames": n}, timeout=10)
            assert r.status_code == 201, r.text
            sid = r.json()["id"]
            while not (seen and seen[-1][0] == "status" and seen[-1][1].get("event") == "end"):
                msg = ws.recv(timeout=300)
                if isinstance(msg, str):
                    continue
                sub, _ = struct.unpack_from("<IQ", msg, 1)
                if sub == 1:
                    seen.append(("cloud", decode_point_cloud(msg[13:])))
                elif (ev := json.loads(msg[13:])).get("id") == sid:
                    seen.append(("status", ev))
        st = _get(f"{url}/streams/{sid}")
    finally:
        stop_daemon(proc)
    assert st["state"] == "done" and st["frames_done"] == n
    clouds = [c for kind, c in seen if kind == "cloud" and len(c) and set(c["frame"].tolist()) <= set(range(n))]
    frames = [e for kind, e in seen if kind == "status" and e["event"] == "frame"]
    assert [e["frame"] for e in frames] == list(range(n))
    assert [set(c["frame"].tolist()) for c in clouds[-n:]] == [{k} for k in range(n)]
    assert [len(c) for c in clouds[-n:]] == [f["points"] for f in st["frames"]]
    assert seen[-1][1]["frames"] == n
