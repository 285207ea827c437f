"""REST: record_raw on a scan, its size in GET /scans/{id}, reprocess into a linked scan, spectrum, removal."""

from __future__ import annotations

import io

import numpy as np
import pytest

from lidard.raw import reprocess
from lidard.raw.capture import capture_size_bytes
from tests.helpers.raw_capture import RecordingFake
from tests.helpers.deadlines import WAIT_S


def _points(client, scan_id):
    r = client.get(f"/scans/{scan_id}/points", params={"format": "npz"})
    assert r.status_code == 200, r.text
    return np.load(io.BytesIO(r.content))["points"]


@pytest.fixture
def recorded(make_client):
    inst = RecordingFake()
    c = make_client(instrument=inst)
    r = c.post("/scans", json={"pattern": "roi", "rows": [0, 2], "cols": [0, 12], "record_raw": True,
                               "formats": ["npz"]})
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    c.app.state.worker.wait(sid, timeout_s=WAIT_S)
    return c, sid, inst


def test_a_recorded_scan_reports_its_capture_size(recorded):
    c, sid, inst = recorded
    rec = c.get(f"/scans/{sid}").json()
    assert rec["state"] == "done" and rec["request"]["record_raw"] is True
    raw = c.app.state.store.scan_dir(sid) / "raw.zarr"
    assert inst.raw_paths == [raw]
    assert rec["raw_bytes"] == capture_size_bytes(raw) > 24 * 2 * 1024 * 2 // 4   # int16 noise compresses < 4x
    plain = c.post("/scans", json={"pattern": "roi", "rows": [0, 1], "cols": [0, 4]}).json()["id"]
    c.app.state.worker.wait(plain, timeout_s=WAIT_S)
    assert c.get(f"/scans/{plain}").json()["raw_bytes"] is None and inst.raw_paths[-1] is None


def test_reprocessing_with_the_original_settings_gives_the_same_points(recorded):
    c, sid, _ = recorded
    r = c.post(f"/scans/{sid}/reprocess", json={})
    assert r.status_code == 201, r.text
    new = r.json()
    assert new["reprocessed_from"] == sid and new["state"] == "done" and new["id"] != sid
    assert new["request"]["record_raw"] is False and new["raw_bytes"] is None
    assert new["formats"] == ["npz"] and new["counts"]["points"] == c.get(f"/scans/{sid}").json()["counts"]["points"]
    assert np.array_equal(_points(c, new["id"]), _points(c, sid))
    side = c.get(f"/scans/{new['id']}/sidecar", params={"format": "npz"}).json()
    assert side["reprocessed_from"] == sid and side["dsp"]["estimator"] == "newton"


def test_reprocessing_with_another_estimator_gives_that_estimators_points(recorded):
    c, sid, _ = recorded
    new = c.post(f"/scans/{sid}/reprocess", json={"estimator": "jacobsen", "formats": ["ply", "npz"]}).json()
    raw = c.app.state.store.scan_dir(sid) / "raw.zarr"
    from lidard.raw import ReprocessSettings
    ref = reprocess(raw, ReprocessSettings(estimator="jacobsen")).points
    got = _points(c, new["id"])
    assert np.array_equal(got, ref) and not np.array_equal(got["range"], _points(c, sid)["range"])
    assert new["request"]["reprocess"] == {"estimator": "jacobsen"} and sorted(new["formats"]) == ["npz", "ply"]


def test_spectrum_of_one_pixel(recorded):
    c, sid, _ = recorded
    r = c.get(f"/scans/{sid}/spectrum", params={"row": 1, "col": 3, "pfa": 1e-3})
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["row"] == 1 and d["col"] == 3 and d["dsp"]["pfa"] == 1e-3
    assert len(d["power_v2"]["up"]) == len(d["threshold_v2"]["up"]) == len(d["range_m"])
    assert any(det["ramp"] == "up" for det in d["detections"])
    assert c.get(f"/scans/{sid}/spectrum", params={"row": 50, "col": 3}).status_code == 404


def test_errors_are_named(recorded):
    c, sid, _ = recorded
    assert c.post("/scans/NOPE/reprocess", json={}).status_code == 404
    before = len(c.get("/scans").json()["scans"])
    r = c.post(f"/scans/{sid}/reprocess", json={"phase_noise": "on"})
    assert r.status_code == 422 and "no monitor 'mzi' channel" in r.json()["detail"]
    assert len(c.get("/scans").json()["scans"]) == before          # refused before any record is made
    r = c.post(f"/scans/{sid}/reprocess", json={"estimator": "fft"})
    assert r.status_code == 422
    r = c.post(f"/scans/{sid}/reprocess", json={"pfa": 0.5})
    assert r.status_code == 422
    r = c.post("/scans", json={"pattern": "adaptive", "record_raw": True})
    assert r.status_code == 422 and "record_raw" in r.text


def test_removing_the_capture_frees_it_and_reprocessing_then_says_why(recorded):
    c, sid, _ = recorded
    raw = c.app.state.store.scan_dir(sid) / "raw.zarr"
    r = c.delete(f"/scans/{sid}/raw")
    assert r.status_code == 200 and r.json()["raw_bytes"] is None and not raw.exists()
    assert c.get(f"/scans/{sid}/points", params={"format": "npz"}).status_code == 200   # the cloud stays
    r = c.post(f"/scans/{sid}/reprocess", json={})
    assert r.status_code == 409 and "no raw capture" in r.json()["detail"]
    assert c.delete(f"/scans/{sid}/raw").status_code == 409
