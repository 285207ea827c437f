"""The opt-in Foxglove live server, seen by a plain WebSocket client on loopback (``websockets``).

Foxglove WebSocket protocol: the server sends ``serverInfo`` and ``advertise`` (JSON text frames),
the client subscribes to a channel id, then gets binary frames: opcode 0x01, u32 subscription id,
u64 log time (ns), the message (here a foxglove.PointCloud in protobuf).
"""

import json
import struct
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient
from websockets.sync.client import connect

from tests.helpers.fakes import FakeInstrument

from lidard.api.app import WorkerOptions, create_app
from lidard.config import ConfigError, load_config
from lidard.outputs.channels import POINTS_TOPIC, STATUS_TOPIC
from lidard.outputs.mcap import decode_point_cloud
from tests.helpers.deadlines import WAIT_S

T = WAIT_S  # a deadline for a hung test (tests/helpers/deadlines.py)
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def _until(cond, what):
    deadline = time.monotonic() + T
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.01)  # polling interval only; the deadline decides


def _json_until(ws, op):
    while True:
        msg = ws.recv(timeout=T)
        if isinstance(msg, str) and json.loads(msg).get("op") == op:
            return json.loads(msg)


def _live_cfg(tmp_path, **live):
    cfg_path = tmp_path / "live.toml"
    body = "\n".join(f"{k} = {json.dumps(v)}" for k, v in live.items())
    cfg_path.write_text(f'[live]\n{body}\n')
    return load_config(cfg_path)


def test_foxglove_client_receives_the_point_cloud_with_every_point(tmp_path):
    cfg = _live_cfg(tmp_path, foxglove=True, foxglove_port=0)
    assert cfg.live.foxglove_host == "127.0.0.1"  # loopback unless configured otherwise
    app = create_app(cfg, instrument=FakeInstrument(), data_dir=tmp_path / "data", worker_options=WorkerOptions(progress_interval_s=0.0))
    with TestClient(app) as c:
        fox = app.state.foxglove
        with connect(f"ws://127.0.0.1:{fox.port}", subprotocols=SUBPROTOCOLS, open_timeout=T) as ws:
            channels = {ch["topic"]: ch for ch in _json_until(ws, "advertise")["channels"]}
            assert channels[POINTS_TOPIC]["schemaName"] == "foxglove.PointCloud"
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 1, "channelId": channels[POINTS_TOPIC]["id"]},
                {"id": 2, "channelId": channels[STATUS_TOPIC]["id"]}]}))
            _until(lambda: fox.channels.points.has_sinks(), "the subscription to reach the server")
            sid = c.post("/scans", json={"pattern": "roi", "rows": [0, 3], "cols": [0, 20]}).json()["id"]
            assert app.state.worker.wait(sid, T).state == "done"
            expected = c.get(f"/scans/{sid}").json()["counts"]["points"]
            clouds, ended = [], False
            while not (clouds and ended):
                frame = ws.recv(timeout=T)
                if isinstance(frame, str):
                    continue
                assert frame[0] == 0x01  # message data
                sub, _log_time = struct.unpack_from("<IQ", frame, 1)
                if sub == 1:
                    clouds.append(decode_point_cloud(frame[13:]))
                elif json.loads(frame[13:]).get("event") == "end":
                    ended = True
    # the fake hands over no batches: the one cloud is the whole scan
    assert len(clouds[-1]) == expected > 0
    np.testing.assert_allclose(clouds[-1]["range"], 1.0 + 0.001 * clouds[-1]["col"], rtol=1e-6)
    assert app.state.foxglove is not None  # closed with the app, no error


def test_foxglove_is_off_by_default_and_config_keys_are_checked(tmp_path):
    assert load_config().live.foxglove is False
    app = create_app(load_config(), instrument=FakeInstrument(), data_dir=tmp_path / "data")
    with TestClient(app):
        assert app.state.foxglove is None
    with pytest.raises(ConfigError, match="foxglove_port"):
        _live_cfg(tmp_path, foxglove=True, foxglove_port=70000)
    with pytest.raises(ConfigError, match="foxglove_hots"):
        _live_cfg(tmp_path, foxglove_hots="0.0.0.0")


def test_foxglove_gets_each_batch_then_the_whole_cloud(tmp_path):
    from tests.helpers.fakes import StreamingInstrument

    inst = StreamingInstrument(n=50)
    inst.release.set()
    app = create_app(_live_cfg(tmp_path, foxglove=True, foxglove_port=0), instrument=inst,
                     data_dir=tmp_path / "data", worker_options=WorkerOptions(progress_interval_s=0.0))
    with TestClient(app) as c:
        fox = app.state.foxglove
        with connect(f"ws://127.0.0.1:{fox.port}", subprotocols=SUBPROTOCOLS, open_timeout=T) as ws:
            chan = {ch["topic"]: ch for ch in _json_until(ws, "advertise")["channels"]}[POINTS_TOPIC]
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": chan["id"]}]}))
            _until(lambda: fox.channels.points.has_sinks(), "the subscription to reach the server")
            sid = c.post("/scans", json={"pattern": "roi", "rows": [0, 2], "cols": [0, 4]}).json()["id"]
            assert app.state.worker.wait(sid, T).state == "done"
            sizes = []
            while sum(sizes) < 100:
                frame = ws.recv(timeout=T)
                if not isinstance(frame, str):
                    sizes.append(len(decode_point_cloud(frame[13:])))
    assert sizes == [25, 25, 50]


def test_foxglove_gets_each_stream_frame_as_it_completes_in_order(tmp_path):
    """A 5-frame stream: 5 PointClouds, one per frame in frame order, each holding exactly that frame's
    points (the fake's ground truth: range 1 m + 1 mm per column + 1 cm per frame), each followed by
    the frame's status event with its index, and the stream's end event last."""
    n = 5
    app = create_app(_live_cfg(tmp_path, foxglove=True, foxglove_port=0), instrument=FakeInstrument(),
                     data_dir=tmp_path / "data", worker_options=WorkerOptions(progress_interval_s=0.0))
    with TestClient(app) as c:
        fox = app.state.foxglove
        with connect(f"ws://127.0.0.1:{fox.port}", subprotocols=SUBPROTOCOLS, open_timeout=T) as ws:
            channels = {ch["topic"]: ch for ch in _json_until(ws, "advertise")["channels"]}
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 1, "channelId": channels[POINTS_TOPIC]["id"]},
                {"id": 2, "channelId": channels[STATUS_TOPIC]["id"]}]}))
            _until(lambda: fox.channels.points.has_sinks() and fox.channels.status.has_sinks(),
                   "the subscriptions to reach the server")
            r = c.post("/streams", json={"pattern": "roi", "rows": [0, 3], "cols": [0, 10], "frames": n})
            assert r.status_code == 201, r.text
            sid = r.json()["id"]
            seen = []          # ("cloud", points) and ("status", event) in arrival order
            while not (seen and seen[-1][0] == "status" and seen[-1][1].get("event") == "end"
                       and seen[-1][1].get("id") == sid):
                msg = ws.recv(timeout=T)
                if isinstance(msg, str):
                    continue
                sub, _log_time = struct.unpack_from("<IQ", msg, 1)
                if sub == 1:
                    seen.append(("cloud", decode_point_cloud(msg[13:])))
                else:
                    ev = json.loads(msg[13:])
                    if ev.get("id") == sid:
                        seen.append(("status", ev))
        status = c.get(f"/streams/{sid}").json()
    assert status["state"] == "done" and status["frames_done"] == n
    kinds = [k for k, _ in seen]
    assert kinds == ["cloud", "status"] * n + ["status"]
    for k in range(n):
        cloud, ev = seen[2 * k][1], seen[2 * k + 1][1]
        assert ev["event"] == "frame" and ev["frame"] == k and ev["points"] == len(cloud) > 0
        assert set(cloud["frame"].tolist()) == {k}
        np.testing.assert_allclose(cloud["range"], 1.0 + 0.001 * cloud["col"] + 0.01 * k, rtol=1e-6)
    assert seen[-1][1]["frames"] == n and seen[-1][1]["state"] == "done"
