"""Store: WAL mode, restart recovery, scan records, calibrations with their drive waveform."""

import re
import sqlite3

import numpy as np
import pytest

from lidard.instrument import CalibrationResult
from lidard.store import Store, StoreError, new_id


def test_wal_mode_and_files(tmp_path):
    s = Store(tmp_path / "data")
    assert s.journal_mode() == "wal"
    assert (tmp_path / "data" / "lidard.sqlite3").is_file()
    # an outside reader sees WAL too
    con = sqlite3.connect(tmp_path / "data" / "lidard.sqlite3")
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    con.close()
    s.close()


def test_ids_are_short_url_safe_and_sortable():
    ids = [new_id() for _ in range(200)]
    assert all(re.fullmatch(r"[0-9A-HJKMNP-TV-Z]{16}", i) for i in ids)
    assert ids == sorted(ids)
    assert len(set(ids)) == len(ids)
    assert new_id(now_s=4e9) > ids[-1]


def test_restart_marks_running_and_queued_interrupted_keeps_finished(tmp_path):
    s = Store(tmp_path)
    done = s.create_scan({"pattern": "raster"}, pixels_planned=10)
    s.update_scan(done.id, state="done", points=7, pixels_scanned=10, partial=False,
                  files={"ply": "scans/x/scan.ply"}, hardware_time_s=0.25, wall_time_s=1.5)
    running = s.create_scan({"pattern": "raster"})
    s.update_scan(running.id, state="running", progress=0.4)
    queued = s.create_scan({"pattern": "serpentine"})
    s.close()

    s2 = Store(tmp_path)
    assert s2.recovered == 2
    r = s2.get_scan(running.id)
    assert r.state == "interrupted" and "running" in r.error and r.progress == pytest.approx(0.4)
    assert s2.get_scan(queued.id).state == "interrupted"
    d = s2.get_scan(done.id)
    assert (d.state, d.points, d.pixels_scanned, d.files, d.hardware_time_s, d.partial) == \
        ("done", 7, 10, {"ply": "scans/x/scan.ply"}, 0.25, False)
    assert d.request == {"pattern": "raster"}
    s2.close()


def test_list_newest_first_and_filter(tmp_path):
    s = Store(tmp_path)
    a = s.create_scan({"n": 1})
    b = s.create_scan({"n": 2})
    s.update_scan(a.id, state="done")
    assert [r.id for r in s.list_scans()] == [b.id, a.id]
    assert [r.id for r in s.list_scans(state="done")] == [a.id]
    assert s.get_scan("nope") is None


def test_transition_is_compare_and_set(tmp_path):
    s = Store(tmp_path)
    a = s.create_scan({})
    assert s.transition(a.id, ("queued",), state="cancelled")
    assert not s.transition(a.id, ("queued",), state="running")
    assert s.get_scan(a.id).state == "cancelled"


def test_bad_update_is_named(tmp_path):
    s = Store(tmp_path)
    a = s.create_scan({})
    with pytest.raises(StoreError, match="bogus"):
        s.update_scan(a.id, bogus=1)
    with pytest.raises(StoreError, match="state"):
        s.update_scan(a.id, state="exploded")
    with pytest.raises(StoreError, match="not found"):
        s.update_scan("missing", state="done")


def test_calibration_round_trip_with_drive_file(tmp_path):
    s = Store(tmp_path)
    drive = np.linspace(-1, 1, 1001) ** 3
    cal = CalibrationResult(iterations=[{"up_rms_hz": 5e6, "down_rms_hz": 6e6},
                                        {"up_rms_hz": 1e5, "down_rms_hz": 2e5}],
                            reduction={"up": 50.0, "down": 30.0}, converged=True, laser="dfb_default",
                            temperature_c=25.0, drive_v=drive, fs_drive_hz=1e8, meta={"note": "x"})
    cid = s.save_calibration(cal)
    assert (tmp_path / "calibrations" / f"{cid}.npy").is_file()
    other = CalibrationResult(iterations=[], reduction={}, converged=False, laser="ideal", temperature_c=20.0)
    s.save_calibration(other)
    back = s.latest_calibration("dfb_default")
    assert back.meta["id"] == cid and back.meta["note"] == "x"
    assert np.array_equal(back.drive_v, drive)
    assert back.iterations == cal.iterations and back.reduction == cal.reduction and back.converged
    assert s.latest_calibration().laser == "ideal"
    assert s.latest_calibration("dfb_strong_nonlinear") is None


def test_unusable_data_dir_is_a_store_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    with pytest.raises(StoreError, match="file"):
        Store(blocker)
