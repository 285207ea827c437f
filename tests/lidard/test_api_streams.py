"""The streams API on the fake instrument: the list the web viewer follows, and a frame's points in
the viewer's float32 layout, from memory for the newest frames and from the frame's file after."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient

from lidard.api.app import create_app
from lidard.config import load_config
from lidard.live.points import LIVE_FIELDS, decode_points
from tests.helpers.fakes import FakeInstrument

T = 20.0


def test_streams_are_listed_and_each_frame_is_served_in_the_viewer_layout(tmp_path):
    app = create_app(load_config(), instrument=FakeInstrument(), data_dir=tmp_path / "data",
                     progress_interval_s=0.0)
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
