"""The store tracks raw captures: columns (also on an older data directory), removal, deletion, leftovers."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from lidard.raw import RawWriter
from lidard.store import Store, StoreError


def _raw(store, scan_id):
    path = store.scan_dir(scan_id) / "raw.zarr"
    w = RawWriter.create(path, pixels=np.zeros((2, 2)), directions=np.tile([0.0, 0.0, 1.0], (2, 1)), averages=1,
                         channels=("beat",), record_length=8, chunk_pixels=1, attrs={"adc": {}, "dsp": {}})
    w.append(np.ones((2, 1, 8), np.int16), np.zeros(2), np.zeros(2), np.zeros(2))
    w.close()
    return path


def test_raw_size_and_link_columns_round_trip(tmp_path):
    st = Store(tmp_path)
    a = st.create_scan({"pattern": "roi"})
    b = st.create_scan({"pattern": "roi"})
    st.update_scan(a.id, raw_bytes=1234)
    st.update_scan(b.id, reprocessed_from=a.id)
    assert st.get_scan(a.id).raw_bytes == 1234 and st.get_scan(a.id).reprocessed_from is None
    assert st.get_scan(b.id).reprocessed_from == a.id and st.get_scan(b.id).raw_bytes is None
    st.close()


def test_an_older_data_directory_gets_the_new_columns(tmp_path):
    con = sqlite3.connect(tmp_path / "lidard.sqlite3")
    con.execute("CREATE TABLE scans (id TEXT PRIMARY KEY, state TEXT NOT NULL, request TEXT NOT NULL, "
                "progress REAL NOT NULL DEFAULT 0, stage TEXT NOT NULL DEFAULT 'queued', created REAL NOT NULL, "
                "started REAL, finished REAL, hardware_time_s REAL, wall_time_s REAL, "
                "points INTEGER NOT NULL DEFAULT 0, pixels_scanned INTEGER NOT NULL DEFAULT 0, "
                "pixels_planned INTEGER NOT NULL DEFAULT 0, error TEXT, partial INTEGER NOT NULL DEFAULT 0, "
                "files TEXT NOT NULL DEFAULT '{}', calibration_id TEXT)")
    con.execute("INSERT INTO scans (id, state, request, created) VALUES ('OLD', 'done', '{}', 1.0)")
    con.commit()
    con.close()
    st = Store(tmp_path)
    old = st.get_scan("OLD")
    assert old.raw_bytes is None and old.reprocessed_from is None
    st.update_scan("OLD", raw_bytes=7)
    assert st.get_scan("OLD").raw_bytes == 7
    st.close()


def test_removing_a_capture_keeps_the_scan_and_deleting_a_scan_removes_everything(tmp_path):
    st = Store(tmp_path)
    rec = st.create_scan({})
    path = _raw(st, rec.id)
    st.update_scan(rec.id, raw_bytes=1, state="done")
    assert st.remove_raw(rec.id, path) and not path.exists()
    assert st.get_scan(rec.id).raw_bytes is None and st.remove_raw(rec.id, path) is False
    path = _raw(st, rec.id)
    (st.scan_dir(rec.id) / "scan.ply").write_bytes(b"ply")
    assert st.delete_scan(rec.id) and not st.scan_dir(rec.id).exists() and st.get_scan(rec.id) is None
    assert st.delete_scan(rec.id) is False
    running = st.create_scan({})
    st.update_scan(running.id, state="running")
    with pytest.raises(StoreError, match="is running; cancel it"):
        st.delete_scan(running.id)
    st.close()


def test_opening_sweeps_a_killed_writers_temporary_chunk_files(tmp_path):
    st = Store(tmp_path)
    rec = st.create_scan({})
    path = _raw(st, rec.id)
    st.close()
    torn = path / "segments" / "c" / "1" / "0" / "0.3f2a9c.partial"
    torn.write_bytes(b"half a chunk")
    st = Store(tmp_path)
    assert st.swept_tmp == 1 and not torn.exists() and (path / "segments" / "c" / "0" / "0" / "0").is_file()
    st.close()


def test_a_scan_cut_by_a_dead_daemon_still_reports_its_captures_prefix(tmp_path):
    st = Store(tmp_path)
    rec = st.create_scan({})
    st.update_scan(rec.id, state="running")
    path = _raw(st, rec.id)
    st.close()
    st = Store(tmp_path)             # the next daemon
    got = st.get_scan(rec.id)
    assert got.state == "interrupted" and got.raw_bytes == sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
    st.close()
