"""The streams API on the fake instrument: the list the web viewer follows, and a frame's points in
the viewer's float32 layout, from memory for the newest frames and from the frame's file after."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient

from lidard.api.app import WorkerOptions, create_app
from lidard.config import load_config
from lidard.live.points import LIVE_FIELDS, decode_points
from tests.helpers.fakes import FakeInstrument

T = 20.0


def test_streams_are_listed_and_each_frame_is_served_in_the_viewer_layout(tmp_path):
    app = create_app(load_config(), instrument=FakeInstrument(), data_dir=tmp_path / "data",
                     worker_options=WorkerOptions(progress_interval_s=0.0))
    with TestClient(app) as c:
        assert c.get("/streams").json() == {"streams": [], "running": None}
        ids = []
        for frames in (3, 4):
            r = c.post("/streams", json={"pattern": "roi", "rows": [0, 3], "cols": [0, 10], "frames": frames})
            assert r.status_code == 201, r.text
            ids.append(r.json()["id"])
        for sid in ids:
            assert app.state.streams[sid].done.wait(T)
        listing = c.get("/streams").json()
        assert [s["id"] for s in listing["streams"]] == ids[::-1] and listing["running"] is None
        assert [s["frames_done"] for s in listing["streams"]] == [4, 3]
        sid = ids[1]
        job = app.state.streams[sid]
        job.keep_frames = 2                 # as if older frames had left memory: frame 0 comes from its file
        job.recent.pop(0)
        for k in range(4):
            r = c.get(f"/streams/{sid}/frames/{k}/live")
            assert r.status_code == 200
            assert r.headers["X-Lidard-Fields"] == ",".join(LIVE_FIELDS) and r.headers["X-Lidard-Frame"] == str(k)
            pts = decode_points(r.content)
            side = job.frames[k]
            assert len(pts["range"]) == side["points"] == int(r.headers["X-Lidard-Count"]) > 0
            # the fake's ground truth for frame k
            np.testing.assert_allclose(pts["range"], 1.0 + 0.001 * pts["col"] + 0.01 * k, rtol=1e-6)
        missing = c.get(f"/streams/{sid}/frames/4/live")
        assert missing.status_code == 404 and "frames done: 4" in missing.text
        assert c.get("/streams/nope/frames/0/live").status_code == 404


def test_a_track_stream_budgets_its_first_frame_from_the_configured_chirp(tmp_path):
    """POST /streams pattern track: the router hands the planner the hardware time of one pixel from the
    configuration (averages x chirp period + settle), so frame 0's budget is margin / rate / (2 x that)
    (no frames measured yet), and the frame visits no more pixels than that."""
    cfg = load_config()
    app = create_app(cfg, instrument=FakeInstrument(), data_dir=tmp_path / "data", worker_options=WorkerOptions(progress_interval_s=0.0))
    with TestClient(app) as c:
        r = c.post("/streams", json={"pattern": "track", "frame_rate_hz": 20, "averages": 2, "frames": 2})
        assert r.status_code == 201, r.text
        job = app.state.streams[r.json()["id"]]
        assert job.done.wait(T) and job.state == "done", job.error
    pixel_s = 2 * cfg.chirp.period_s + cfg.scan.settle_s
    plan0 = job.frames[0]["plan"]
    assert plan0["pattern"] == "track" and plan0["budget_pixels"] == int(0.95 / 20 / (2 * pixel_s))
    assert 0 < job.frames[0]["pixels_planned"] <= plan0["budget_pixels"]
