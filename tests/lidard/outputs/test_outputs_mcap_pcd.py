"""MCAP (Foxglove topics) and PCD outputs: every point round-trips, read back with independent readers."""

import json

import numpy as np
import pytest
from mcap.reader import make_reader

from lidard.instrument.types import POINT_DTYPE
from lidard.outputs.channels import DEVICES_TOPIC, PACKED_DTYPE, POINTS_TOPIC, STATUS_TOPIC
from lidard.outputs.mcap import read_mcap, write_mcap
from lidard.outputs.pcd import read_pcd, write_pcd
from lidard.outputs import FORMATS, format_of, read_points, write_points


def cloud(n=257, seed=3):
    rng = np.random.default_rng(seed)
    pts = np.zeros(n, POINT_DTYPE)
    for f in ("x", "y", "z", "range", "velocity", "intensity", "snr_db"):
        pts[f] = rng.normal(size=n)
    pts["row"], pts["col"] = rng.integers(0, 128, n), rng.integers(0, 128, n)
    pts["return_index"], pts["valid"] = rng.integers(0, 3, n), rng.integers(0, 2, n)
    pts["t"] = np.sort(rng.uniform(0, 2.0, n)) + 1e-9  # needs float64 to keep ns
    return pts


def test_mcap_every_point_and_the_status_read_back_with_the_mcap_reader(tmp_path):
    pts = cloud()
    meta = {"scan_id": "S1", "partial": False, "pixels_scanned": 300, "pixels_planned": 300,
            "hardware_time_s": 2.0, "devices": [{"name": "fpsa", "state": "ready"}]}
    path = write_mcap(tmp_path / "scan.mcap", pts, meta, time_ns=1_700_000_000_123_456_789)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {ch.topic: ch for ch in summary.channels.values()}
        assert set(topics) == {POINTS_TOPIC, STATUS_TOPIC, DEVICES_TOPIC}
        assert summary.schemas[topics[POINTS_TOPIC].schema_id].name == "foxglove.PointCloud"
        assert topics[POINTS_TOPIC].message_encoding == "protobuf"
        assert topics[STATUS_TOPIC].message_encoding == "json"
        msgs = {ch.topic: m for _, ch, m in reader.iter_messages()}
    assert msgs[POINTS_TOPIC].log_time == 1_700_000_000_123_456_789
    assert json.loads(msgs[DEVICES_TOPIC].data) == {"devices": meta["devices"]}
    got, statuses = read_mcap(path)
    assert got.dtype.names == PACKED_DTYPE.names and len(got) == len(pts)
    for f in ("x", "y", "z", "range", "velocity", "intensity", "snr_db"):
        np.testing.assert_array_equal(got[f], pts[f])
    for f in ("row", "col"):
        np.testing.assert_array_equal(got[f], pts[f].astype(np.int64))
    np.testing.assert_array_equal(got["t"], pts["t"])  # float64 on the wire: ns survive
    assert statuses == [{"event": "end", "scan_id": "S1", "partial": False, "pixels_scanned": 300,
                         "pixels_planned": 300, "hardware_time_s": 2.0, "stop_reason": None,
                         "calibration_id": None, "points": len(pts)}]


def test_pcd_is_binary_v07_with_every_field_and_round_trips(tmp_path):
    pts = cloud(100)
    path = write_pcd(tmp_path / "scan.pcd", pts)
    raw = path.read_bytes()
    header, _, body = raw.partition(b"DATA binary\n")
    lines = dict(ln.split(" ", 1) for ln in header.decode().splitlines() if not ln.startswith("#"))
    assert lines["VERSION"] == "0.7" and lines["POINTS"] == "100" and lines["WIDTH"] == "100"
    assert lines["HEIGHT"] == "1"
    assert lines["FIELDS"].split()[:3] == ["x", "y", "z"]  # what PCL/Open3D take as the position
    sizes = [int(s) for s in lines["SIZE"].split()]
    assert len(body) == 100 * sum(sizes)  # packed records, nothing else
    got = read_pcd(path)
    for f in POINT_DTYPE.names:
        np.testing.assert_array_equal(got[f], pts[f])
    back = read_points(path)  # through the format dispatch, as POINT_DTYPE
    assert back.dtype == POINT_DTYPE
    np.testing.assert_array_equal(back, pts)


def test_format_dispatch_writes_sidecars_and_knows_the_new_formats(tmp_path):
    pts = cloud(10)
    assert {"pcd", "mcap"} <= set(FORMATS)
    for fmt in ("pcd", "mcap"):
        files = write_points(tmp_path / f"s.{fmt}", pts, {"scan_id": "S"})
        assert format_of(files[0]) == fmt and files[1].name == f"s.{fmt}.json"
        back = read_points(files[0])
        np.testing.assert_array_equal(back["range"], pts["range"])
        np.testing.assert_array_equal(back["t"], pts["t"])
    with pytest.raises(ValueError, match=r"\.mcap"):
        format_of(tmp_path / "s.xyz")
