"""Nothing lost across ``kill -9`` (issue 6, "Nothing lost"), with a REAL daemon process.

``python -m lidard --config config/sim.toml`` (child-process simulated bench, temp data dir, port 0):
finish one scan, start a large second one, wait until it reports progress, SIGKILL the daemon (its
whole process group, so the bench child goes too), restart on the same data dir. Then: the finished
scan and its files are intact (PLY parsed with plyfile, count equal to the store's), the interrupted
scan is marked ``interrupted``, and no half-written file exists anywhere under the data dir (no temp
file, every file parses). All waiting is bounded polling with deadlines, never a sleep that decides.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import httpx
import numpy as np
import pytest
from plyfile import PlyData

from tests.helpers.daemon import kill_group, poll, start_daemon
from tests.helpers.deadlines import HTTP_S, WAIT_S

pytestmark = pytest.mark.slow  # two real daemon processes

REPO = Path(__file__).resolve().parents[2]
_start_daemon, _kill_group, _poll = start_daemon, kill_group, poll   # names the other e2e files import


def _scan(client: httpx.Client, sid: str) -> dict:
    r = client.get(f"/scans/{sid}")
    assert r.status_code == 200, r.text
    return r.json()


def _assert_every_file_parses(data_dir: Path) -> int:
    n = 0
    for p in data_dir.rglob("*"):
        if p.is_dir():
            continue
        n += 1
        assert not p.name.endswith(".tmp"), f"half-written file left behind: {p}"
        if p.suffix == ".ply":
            PlyData.read(str(p))
        elif p.suffix == ".json":
            json.loads(p.read_text())
        elif p.suffix == ".npy":
            np.load(p)
        elif p.suffix == ".npz":
            with np.load(p) as z:
                list(z.keys())
        elif p.name == "lidard.sqlite3":
            with sqlite3.connect(f"file:{p}?mode=ro", uri=True) as db:
                assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        elif p.name.startswith("lidard.sqlite3-"):
            pass        # WAL / shared-memory companions of the database
        elif p.name == "lidard.lock":
            assert p.read_text().strip().isdigit()   # the holder's PID (flock dies with it)
        else:
            pytest.fail(f"unexpected file under the data dir: {p}")
    return n


def test_kill_9_mid_scan_then_restart_loses_nothing(tmp_path):
    data_dir = tmp_path / "data"
    proc, url = _start_daemon(data_dir)
    try:
        with httpx.Client(base_url=url, timeout=HTTP_S) as c:
            r = c.post("/scans", json={"pattern": "roi", "rows": [44, 48], "cols": [60, 70],
                                       "max_range_m": 2.0, "formats": ["ply", "npz"]})
            assert r.status_code == 201, r.text
            first = r.json()["id"]
            done = _poll(lambda: (s := _scan(c, first))["state"] in ("done", "failed") and s, WAIT_S, "scan 1")
            assert done["state"] == "done", done
            r = c.post("/scans", json={"pattern": "raster", "averages": 8, "max_range_m": 2.0,
                                       "formats": ["ply"]})
            assert r.status_code == 201, r.text
            second = r.json()["id"]
            _poll(lambda: _scan(c, second)["progress"] > 0, WAIT_S, "scan 2 to report progress")
            assert _scan(c, second)["state"] == "running"
    finally:
        _kill_group(proc)                       # kill -9, mid-scan

    proc, url = _start_daemon(data_dir)
    try:
        with httpx.Client(base_url=url, timeout=HTTP_S) as c:
            one = _scan(c, first)
            two = _scan(c, second)
    finally:
        _kill_group(proc)
    assert one["state"] == "done" and two["state"] == "interrupted"
    assert "daemon stopped" in (two["error"] or "")
    # the finished scan's files are complete: each parses with the stored point count
    rec = sqlite3.connect(f"file:{data_dir / 'lidard.sqlite3'}?mode=ro", uri=True).execute(
        "SELECT points, files FROM scans WHERE id = ?", (first,)).fetchone()
    points, files = rec[0], json.loads(rec[1])
    assert set(files) == {"ply", "npz"} and points > 0
    assert len(PlyData.read(str(data_dir / files["ply"]))["vertex"]) == points
    with np.load(data_dir / files["npz"]) as z:
        assert len(z[z.files[0]]) == points
    assert _assert_every_file_parses(data_dir) >= 4


def test_restart_removes_temp_files_of_an_interrupted_write(tmp_path):
    from lidard.store import Store
    # what a kill -9 inside atomic_write leaves: a hidden temp file next to where the file would go
    scan_dir = tmp_path / "scans" / "01M8ZZZZZZZZZZZZ"
    scan_dir.mkdir(parents=True)
    (scan_dir / ".scan.ply.k3j4h5.tmp").write_bytes(b"ply\nformat binary_little_endian 1.0\n")
    (tmp_path / "calibrations").mkdir()
    (tmp_path / "calibrations" / ".01M8.npy.abc.tmp").write_bytes(b"\x93NUMPY")
    keep = scan_dir / "notes.txt"
    keep.write_text("not ours to delete")
    store = Store(tmp_path)
    try:
        assert store.swept_tmp == 2
        assert not list(tmp_path.rglob("*.tmp")) and keep.exists()
    finally:
        store.close()
