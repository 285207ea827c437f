"""The viewer's page and data endpoints in-process: GET /, static files, /points/live, calibration history."""

import re

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.helpers.fakes import StreamingInstrument

from lidard.api.app import WorkerOptions, create_app
from lidard.api.routers.viewer import STATIC_DIR
from lidard.config import load_config
from lidard.instrument.types import POINT_DTYPE
from lidard.live.points import LIVE_FIELDS, LivePoints, decode_points, encode_points
from lidard.outputs.npz import read_npz
from tests.helpers.deadlines import WAIT_S

T = WAIT_S  # a deadline for a hung test (tests/helpers/deadlines.py)


@pytest.fixture
def client(tmp_path):
    inst = StreamingInstrument()
    app = create_app(load_config(), instrument=inst, data_dir=tmp_path / "data", worker_options=WorkerOptions(progress_interval_s=0.0))
    with TestClient(app) as c:
        yield c, inst, app


def _live(c, sid, since=0, **params):
    r = c.get(f"/scans/{sid}/points/live", params={"since": since, **params})
    assert r.status_code == 200 and r.headers["content-type"] == "application/octet-stream"
    return r, decode_points(r.content)


def test_points_grow_batch_by_batch_and_match_the_file(client):
    c, inst, app = client
    sid = c.post("/scans", json={"pattern": "roi", "rows": [0, 2], "cols": [0, 4], "formats": ["npz"]}).json()["id"]
    assert inst.first_batch.wait(T)
    r, first = _live(c, sid)
    assert r.headers["x-lidard-complete"] == "false"
    assert (r.headers["x-lidard-start"], r.headers["x-lidard-count"], r.headers["x-lidard-total"]) == ("0", "25", "25")
    assert r.headers["x-lidard-fields"] == ",".join(LIVE_FIELDS)
    inst.release.set()
    app.state.worker.wait(sid, T)
    r, rest = _live(c, sid, since=25)
    assert r.headers["x-lidard-complete"] == "true"
    assert (r.headers["x-lidard-start"], r.headers["x-lidard-count"], r.headers["x-lidard-total"]) == ("25", "25", "50")
    pts, _ = read_npz(app.state.store.data_dir / f"scans/{sid}/scan.npz")
    for f in LIVE_FIELDS:  # the two slices are the written cloud, in order, as float32
        np.testing.assert_array_equal(np.concatenate([first[f], rest[f]]), pts[f].astype(np.float32))
    # a client that is up to date gets nothing more, and the final flag
    r, none = _live(c, sid, since=50)
    assert len(none["x"]) == 0 and r.headers["x-lidard-complete"] == "true"
    r, lim = _live(c, sid, since=10, limit=5)
    assert r.headers["x-lidard-count"] == "5" and r.headers["x-lidard-complete"] == "false"
    np.testing.assert_array_equal(lim["range"], pts["range"][10:15].astype(np.float32))


def test_points_of_a_scan_no_longer_buffered_come_from_its_file(client):
    c, inst, app = client
    inst.release.set()
    sid = c.post("/scans", json={"pattern": "roi", "rows": [0, 2], "cols": [0, 4], "formats": ["ply"]}).json()["id"]
    app.state.worker.wait(sid, T)
    app.state.live = LivePoints()  # as after the buffer moved on to newer scans
    r, got = _live(c, sid, since=40)
    assert r.headers["x-lidard-total"] == "50" and r.headers["x-lidard-complete"] == "true"
    np.testing.assert_allclose(got["range"], np.linspace(0.5, 1.5, 50)[40:].astype(np.float32))
    assert c.get("/scans/nope/points/live").status_code == 404
    assert c.get(f"/scans/{sid}/points/live", params={"since": -1}).status_code == 422


def test_live_buffer_keeps_the_newest_scans_and_final_cloud_wins():
    live = LivePoints(keep=2)
    a = np.zeros(3, POINT_DTYPE)
    a["range"] = [1, 2, 3]
    live("s1", a[:2], False)
    assert live.since("s1", 0).total == 2 and not live.since("s1", 0).complete
    live("s1", a, True)   # the final cloud replaces the batches
    live("s1", a[:1], False)  # a late batch after the end is ignored
    sl = live.since("s1", 1)
    assert (sl.start, sl.total, sl.complete) == (1, 3, True) and list(sl.points["range"]) == [2, 3]
    assert live.since("s1", 99).start == 3
    live("s2", a, True)
    live("s3", a, True)
    assert live.since("s1", 0) is None and live.knows("s3")
    with pytest.raises(ValueError, match="keep"):
        LivePoints(keep=0)
    assert len(encode_points(a)) == 3 * len(LIVE_FIELDS) * 4


def test_calibration_history_newest_first(client):
    c, inst, app = client
    assert c.get("/calibration/history").json() == []
    for _ in range(3):
        assert c.post("/calibration/linearize").status_code == 201
    hist = c.get("/calibration/history", params={"limit": 2}).json()
    assert len(hist) == 2 and hist[0]["created"] >= hist[1]["created"]
    assert hist[0]["id"] == c.get("/calibration").json()["id"]
    assert hist[0]["iterations"][0] == {"up_rms_hz": 4e6, "down_rms_hz": 5e6}
    assert c.get("/calibration/history", params={"limit": 0}).status_code == 422


def test_page_and_scripts_are_served_from_the_package_and_nothing_from_the_network(client):
    c, _, _ = client
    page = c.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert '"three": "/viewer/vendor/three.module.min.js"' in page.text
    for name in ("viewer.js", "cloud.js", "panels.js", "viewer.css", "vendor/three.module.min.js",
                 "vendor/OrbitControls.js"):
        assert c.get(f"/viewer/{name}").status_code == 200, name
    # offline: no page or script of ours loads anything from another host
    for path in STATIC_DIR.rglob("*"):
        if path.suffix in (".html", ".js", ".css") and "vendor" not in path.parts:
            text = path.read_text()
            assert not re.search(r"""(src|href)=["']?(https?:)?//|from\s+["'](https?:)?//|url\((https?:)?//""",
                                 text), path
    assert "three@0.170.0" in (STATIC_DIR / "vendor" / "VERSION").read_text()


def test_scan_written_as_mcap_and_pcd_is_served_in_both(client):
    c, inst, app = client
    inst.release.set()
    r = c.post("/scans", json={"pattern": "roi", "rows": [0, 2], "cols": [0, 4], "formats": ["mcap", "pcd"]})
    assert r.status_code == 201
    sid = r.json()["id"]
    app.state.worker.wait(sid, T)
    assert c.get(f"/scans/{sid}").json()["formats"] == ["mcap", "pcd"]
    from lidard.outputs.mcap import read_mcap
    from lidard.outputs.pcd import read_pcd
    for fmt, reader in (("mcap", lambda p: read_mcap(p)[0]), ("pcd", read_pcd)):
        body = c.get(f"/scans/{sid}/points", params={"format": fmt})
        assert body.status_code == 200
        path = app.state.store.data_dir / f"x.{fmt}"
        path.write_bytes(body.content)
        np.testing.assert_allclose(reader(path)["range"], np.linspace(0.5, 1.5, 50).astype(np.float32))
    bad = c.post("/scans", json={"pattern": "roi", "rows": [0, 2], "cols": [0, 4], "formats": ["xyz"]})
    assert bad.status_code == 422


def test_a_failing_point_listener_does_not_stop_the_scan(client):
    c, inst, app = client
    seen = []

    def broken(scan_id, points, final):
        seen.append((len(points), final))
        raise RuntimeError("viewer bug")

    app.state.worker.add_point_listener(broken)
    inst.release.set()
    sid = c.post("/scans", json={"pattern": "roi", "rows": [0, 2], "cols": [0, 4]}).json()["id"]
    assert app.state.worker.wait(sid, T).state == "done"
    assert seen == [(25, False), (25, False), (50, True)]
