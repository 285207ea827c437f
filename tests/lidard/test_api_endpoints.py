"""REST API in-process against a FakeInstrument: every endpoint and its error codes."""

import io
import json

import numpy as np
import pytest

from tests.helpers.api import app_client
from tests.helpers.fakes import FakeInstrument
from tests.helpers.deadlines import WAIT_S

T = WAIT_S  # a deadline for a hung test (tests/helpers/deadlines.py)
SMALL = {"pattern": "roi", "rows": [0, 3], "cols": [0, 20]}


@pytest.fixture
def fake_api(make_client):
    """``fake_api(**FakeInstrument kwargs)`` -> (client, instrument, app), queue of 3."""
    def make(**kw):
        inst = FakeInstrument(**kw)
        c = make_client(inst, progress_interval_s=0.0, max_queue=3)
        return c, inst, c.app
    return make


def wait_done(app, scan_id):
    return app.state.worker.wait(scan_id, T)


def test_health_devices_scanner(fake_api):
    c, inst, app = fake_api()
    h = c.get("/health").json()
    assert h["status"] == "ok" and h["simulated"] is True and h["worker_running"] is True
    d = c.get("/devices").json()["devices"]
    assert {x["name"] for x in d} == {"fpsa", "awg", "digitizer", "controller"}
    s = c.get("/scanner").json()
    assert s["pixels"] == [128, 128] and s["bonded_rows"] == 96
    assert c.get("/docs").status_code == 200
    assert "/scans/{scan_id}/events" in c.get("/openapi.json").json()["paths"]


def test_create_scan_201_location_and_fetch_points(fake_api):
    c, inst, app = fake_api()
    r = c.post("/scans", json={**SMALL, "formats": ["ply", "las", "npz"]})
    assert r.status_code == 201
    sid = r.json()["id"]
    assert r.headers["location"] == f"/scans/{sid}"
    assert r.json()["state"] == "queued" and r.json()["counts"]["pixels_planned"] == 60
    wait_done(app, sid)
    s = c.get(f"/scans/{sid}").json()
    assert s["state"] == "done" and s["counts"]["points"] == 60 and s["progress"] == 1.0
    assert s["timing"]["hardware_time_s"] == pytest.approx(6e-3) and s["timing"]["finished"] >= s["timing"]["started"]
    assert s["formats"] == ["las", "npz", "ply"]
    npz = c.get(f"/scans/{sid}/points", params={"format": "npz"})
    assert npz.status_code == 200
    with np.load(io.BytesIO(npz.content)) as z:
        assert len(z["points"]) == 60
    ply = c.get(f"/scans/{sid}/points")
    assert ply.status_code == 200 and ply.content.startswith(b"ply\nformat binary_little_endian")
    assert c.get(f"/scans/{sid}/points", params={"format": "las"}).content[:4] == b"LASF"
    lst = c.get("/scans").json()
    assert [x["id"] for x in lst["scans"]] == [sid]


def test_unknown_scan_404(fake_api):
    c, _, _ = fake_api()
    for method, url in [("GET", "/scans/NOPE"), ("GET", "/scans/NOPE/points"), ("DELETE", "/scans/NOPE"),
                        ("GET", "/scans/NOPE/events")]:
        r = c.request(method, url)
        assert r.status_code == 404, url
        assert "NOPE" in r.json()["detail"]


def test_points_409_while_running_and_format_404(fake_api):
    c, inst, app = fake_api(hold_after=5)
    sid = c.post("/scans", json=SMALL).json()["id"]
    assert inst.reached.wait(T)
    r = c.get(f"/scans/{sid}/points")
    assert r.status_code == 409 and "running" in r.json()["detail"]
    assert c.get(f"/scans/{sid}").json()["state"] == "running"
    inst.release.set()
    wait_done(app, sid)
    r = c.get(f"/scans/{sid}/points", params={"format": "las"})
    assert r.status_code == 404 and "ply" in r.json()["detail"]


@pytest.mark.parametrize("body,field", [
    ({"pattern": "spiral"}, "pattern"),
    ({"rows": [5, 2]}, "rows"),
    ({"rows": [0, 1, 2]}, "rows"),
    ({"averages": 0}, "averages"),
    ({"max_range_m": -1}, "max_range_m"),
    ({"formats": ["xyz"]}, "formats"),
    ({"formats": []}, "formats"),
    ({"bogus": 1}, "bogus"),
    ({"pattern": "pixels", "pixels": [[0, 0], [7, 1]]}, "pixels"),
    ({"pattern": "pixels", "pixels": [[0, 200]]}, "pixels"),
    ({"pattern": "roi", "rows": [0, 500]}, "rows"),
])
def test_bad_scan_bodies_are_422_naming_the_field(fake_api, body, field):
    c, inst, _ = fake_api()
    r = c.post("/scans", json=body)
    assert r.status_code == 422, r.text
    assert field in json.dumps(r.json()["detail"])
    assert inst.requests == []


def test_malformed_json_is_422(fake_api):
    c, _, _ = fake_api()
    r = c.post("/scans", content=b"{not json", headers={"content-type": "application/json"})
    assert r.status_code == 422


def test_unbonded_pixel_is_named(fake_api):
    c, _, _ = fake_api()
    r = c.post("/scans", json={"pattern": "pixels", "pixels": [[0, 0], [7, 1]]})
    assert "(7, 1)" in json.dumps(r.json()["detail"])


def test_delete_running_keeps_partial_points(fake_api):
    c, inst, app = fake_api(hold_after=17)
    sid = c.post("/scans", json={**SMALL, "formats": ["npz"]}).json()["id"]
    assert inst.reached.wait(T)
    assert c.delete(f"/scans/{sid}").status_code == 200
    wait_done(app, sid)
    s = c.get(f"/scans/{sid}").json()
    assert s["state"] == "cancelled" and s["partial"] is True and s["counts"]["points"] == 17
    r = c.get(f"/scans/{sid}/points", params={"format": "npz"})
    assert r.status_code == 200 and r.headers["x-lidard-partial"] == "true"
    with np.load(io.BytesIO(r.content)) as z:
        assert len(z["points"]) == 17
        assert json.loads(str(z["meta"]))["partial"] is True


def test_delete_queued_and_queue_fifo_and_limit(fake_api):
    c, inst, app = fake_api(hold_after=1)
    first = c.post("/scans", json=SMALL).json()["id"]
    assert inst.reached.wait(T)
    ids = [c.post("/scans", json={"pattern": "roi", "rows": [0, 1], "cols": [k, k + 1]}).json()["id"]
           for k in range(3)]
    full = c.post("/scans", json=SMALL)
    assert full.status_code == 503 and "queue is full" in full.json()["detail"]
    assert c.get("/scans").json()["queue_length"] == 3
    r = c.delete(f"/scans/{ids[1]}")
    assert r.json()["state"] == "cancelled"
    r = c.get(f"/scans/{ids[1]}/points")
    assert r.status_code == 404
    inst.release.set()
    for i in [first, *ids]:
        wait_done(app, i)
    assert [rq.cols for rq in inst.requests[1:]] == [(0, 1), (2, 3)]


def parse_sse(text):
    events = []
    for block in text.strip().split("\n\n"):
        lines = dict(line.split(": ", 1) for line in block.splitlines() if not line.startswith(":"))
        if lines:
            events.append((lines["event"], json.loads(lines["data"])))
    return events


def test_sse_stream_yields_progress_and_ends(fake_api):
    c, inst, app = fake_api(hold_after=3)
    sid = c.post("/scans", json=SMALL).json()["id"]
    assert inst.reached.wait(T)
    with c.stream("GET", f"/scans/{sid}/events") as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        inst.release.set()
        text = "".join(r.iter_text())
    ev = parse_sse(text)
    kinds = [k for k, _ in ev]
    assert kinds[-1] == "end" and kinds.count("end") == 1 and kinds.count("progress") >= 2
    assert ev[-1][1]["state"] == "done"
    done = [d["pixels_done"] for k, d in ev if k == "progress"]
    assert done == sorted(done) and done[-1] == 60


def test_sse_of_finished_scan_ends_at_once(fake_api):
    c, inst, app = fake_api()
    sid = c.post("/scans", json=SMALL).json()["id"]
    wait_done(app, sid)
    ev = parse_sse(c.get(f"/scans/{sid}/events").text)
    assert len(ev) == 1 and ev[0][0] == "end"
    end = ev[0][1]
    # the end carries the final record as GET /scans/{id} answers it (clients of a daemon that shuts down)
    record = end.pop("scan")
    assert end == {"event": "end", "id": sid, "state": "done", "partial": False, "error": None}
    assert record == c.get(f"/scans/{sid}").json()


def test_calibration_endpoints(fake_api):
    c, inst, app = fake_api()
    assert c.get("/calibration").status_code == 404
    r = c.post("/calibration/linearize")
    assert r.status_code == 201
    body = r.json()
    assert body["iterations"][0]["up_rms_hz"] == 4e6 and body["reduction"] == {"up": 100.0, "down": 50.0}
    assert body["drive_samples"] == 64
    got = c.get("/calibration").json()
    assert got["id"] == body["id"] and len(got["iterations"]) == 2


def test_failed_scan_reports_error(fake_api):
    c, inst, app = fake_api(fail_with=RuntimeError("awg: USB pipe stalled"))
    sid = c.post("/scans", json=SMALL).json()["id"]
    wait_done(app, sid)
    s = c.get(f"/scans/{sid}").json()
    assert s["state"] == "failed" and "awg: USB pipe stalled" in s["error"]
    assert c.get(f"/scans/{sid}/points").status_code == 404


SCENE_TOML = """
name = "wall"
[[target]]
kind = "plane"
point = [0.0, 0.0, 2.0]
normal = [0.0, 0.0, -1.0]
"""


def test_put_scene_toml_json_and_errors(fake_api):
    c, inst, app = fake_api()
    r = c.put("/sim/scene", content=SCENE_TOML, headers={"content-type": "application/toml"})
    assert r.status_code == 200, r.text
    assert r.json() == {"name": "wall", "targets": 1}
    assert inst.scenes[-1]["target"][0]["kind"] == "plane"
    r = c.put("/sim/scene", json={"target": [{"kind": "sphere", "center": [0, 0, 1], "radius": 0.1}]})
    assert r.status_code == 200 and r.json()["targets"] == 1
    r = c.put("/sim/scene", json={"target": [{"kind": "sphere", "center": [0, 0, 1], "radius": -1}]})
    assert r.status_code == 422 and "radius" in json.dumps(r.json())
    r = c.put("/sim/scene", content="this is = = not toml", headers={"content-type": "application/toml"})
    assert r.status_code == 422
    assert len(inst.scenes) == 2


def test_put_scene_on_real_hardware_is_409(fake_api):
    c, inst, app = fake_api(simulated=False)
    r = c.put("/sim/scene", content=SCENE_TOML, headers={"content-type": "application/toml"})
    assert r.status_code == 409 and inst.scenes == []


def test_token_required_when_configured(tmp_path):
    with app_client(tmp_path, token="s3cret") as c:
        # issue 6: reads stay open to observers, mutating requests need the token
        assert c.get("/health").status_code == 200
        assert c.post("/scans", json=SMALL).status_code == 401
        assert c.post("/scans", json=SMALL, headers={"Authorization": "Bearer s3cret"}).status_code == 201


def test_lifespan_closes_instrument(tmp_path):
    inst = FakeInstrument()
    with app_client(tmp_path, inst) as c:
        assert c.get("/health").status_code == 200
    assert inst.closed


def test_points_file_missing_on_disk_is_404_not_500(fake_api):
    c, inst, app = fake_api()
    sid = c.post("/scans", json=SMALL).json()["id"]
    rec = wait_done(app, sid)
    (app.state.store.data_dir / rec.files["ply"]).unlink()
    r = c.get(f"/scans/{sid}/points")
    assert r.status_code == 404 and "missing" in r.json()["detail"]


def test_linearize_device_fault_is_503_naming_the_device(fake_api):
    c, inst, app = fake_api()

    def broken(progress=None):
        raise RuntimeError("awg: drive waveform upload rejected")
    inst.linearize = broken
    r = c.post("/calibration/linearize")
    assert r.status_code == 503 and "awg: drive waveform upload rejected" in r.json()["detail"]


def test_phase_noise_compensation_choice_reaches_the_instrument(fake_api):
    c, inst, app = fake_api()
    sids = []
    for choice in ("on", "off", None):
        body = dict(SMALL) if choice is None else {**SMALL, "phase_noise_compensation": choice}
        r = c.post("/scans", json=body)
        assert r.status_code == 201, r.text
        sids.append(r.json()["id"])
    for sid in sids:
        wait_done(app, sid)
    assert [q.phase_noise_compensation for q in inst.requests] == ["on", "off", None]
    r = c.post("/scans", json={**SMALL, "phase_noise_compensation": "sometimes"})
    assert r.status_code == 422 and "phase_noise_compensation" in r.text


def test_sidecar_endpoint_names_the_config_scene_then_an_uploaded_one(make_client):
    import hashlib

    from lidard.config import CONFIG_DIR, load_config
    cfg = load_config(CONFIG_DIR / "sim.toml")
    c = make_client(FakeInstrument(profile="fpsa128"), cfg=cfg, progress_interval_s=0.0)
    scene_file = cfg.resolve_path(cfg.sim.scene)

    def scan_sidecar():
        sid = c.post("/scans", json={**SMALL, "formats": ["ply"]}).json()["id"]
        c.app.state.worker.wait(sid, T)
        return sid, c.get(f"/scans/{sid}/sidecar", params={"format": "ply"})

    sid, r = scan_sidecar()
    assert r.status_code == 200
    side = r.json()
    assert side["scan_id"] == sid and side["format"] == "ply"
    assert side["scene"] == {"path": str(scene_file.resolve()),
                             "sha256": hashlib.sha256(scene_file.read_bytes()).hexdigest()}
    assert c.get(f"/scans/{sid}/sidecar", params={"format": "las"}).status_code == 404
    assert c.get("/scans/NOPE/sidecar").status_code == 404
    # a scene uploaded with PUT /sim/scene has no file: later sidecars carry the hash of the body sent
    assert c.put("/sim/scene", content=SCENE_TOML, headers={"content-type": "application/toml"}).status_code == 200
    _, r = scan_sidecar()
    assert r.json()["scene"] == {"path": None, "source": "PUT /sim/scene", "name": "wall",
                                 "sha256": hashlib.sha256(SCENE_TOML.encode()).hexdigest()}
