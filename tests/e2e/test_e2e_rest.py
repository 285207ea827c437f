"""REST API on the real instrument composition with an embedded simulated bench (no fakes)."""

import io

import numpy as np
import pytest
from plyfile import PlyData

from lidard.config import load_config
from lidard.instrument import open_instrument
from tests.helpers.api import app_client

pytestmark = pytest.mark.slow  # the REST API on an embedded bench, linearized (~20 s)


def test_post_scan_poll_and_fetch_points_over_rest(tmp_path):
    cfg = load_config("config/sim.toml")
    inst = open_instrument(cfg, scene_path="config/scenes/cal_letters.toml", bench="embedded")
    with app_client(tmp_path, inst, cfg) as client:
        assert client.get("/scanner").json()["bonded_rows"] == 96
        r = client.post("/scans", json={"pattern": "roi", "rows": [44, 46], "cols": [60, 68],
                                        "averages": 2, "max_range_m": 2.0, "formats": ["ply"]})
        assert r.status_code == 201
        sid = r.json()["id"]
        assert r.headers["location"].endswith(sid)
        # the server-sent event stream ends when the scan ends: no polling, no sleeps
        with client.stream("GET", f"/scans/{sid}/events") as events:
            lines = [ln for ln in events.iter_lines() if ln]
        assert any(ln.startswith("event: end") for ln in lines)
        state = client.get(f"/scans/{sid}").json()["state"]
        assert state == "done"
        ply = client.get(f"/scans/{sid}/points", params={"format": "ply"})
        assert ply.status_code == 200
        v = PlyData.read(io.BytesIO(ply.content))["vertex"]
        assert len(v) == 16
        assert np.all(np.abs(np.asarray(v["range"]) - 0.85) < 0.06)
        cal = client.get("/calibration").json()
        assert cal  # the worker linearized first and stored it
