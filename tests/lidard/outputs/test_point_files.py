"""Point-cloud writers: PLY/LAS/NPZ round trips, the sidecar, atomic writes."""

import json
import os

import numpy as np
import pytest

from lidard import outputs
from lidard.outputs import las as las_file
from lidard.outputs import npz as npz_file
from lidard.outputs import ply as ply_file
from lidard.outputs import files
from lidard.instrument import POINT_DTYPE


def make_points(n=200, seed=7):
    rng = np.random.default_rng(seed)
    p = np.zeros(n, dtype=POINT_DTYPE)
    p["x"] = rng.uniform(-0.3, 0.3, n)
    p["y"] = rng.uniform(-0.3, 0.3, n)
    p["z"] = rng.uniform(0.5, 5.0, n)
    p["range"] = np.sqrt(p["x"].astype(float) ** 2 + p["y"] ** 2 + p["z"] ** 2)
    p["velocity"] = rng.normal(0, 1.5, n)
    p["intensity"] = rng.uniform(0.001, 0.4, n)
    p["snr_db"] = rng.uniform(6, 40, n)
    p["row"] = rng.integers(0, 128, n)
    p["col"] = rng.integers(0, 128, n)
    p["return_index"] = rng.integers(0, 2, n)
    p["t"] = np.sort(rng.uniform(0, 0.5, n))
    p["valid"] = rng.integers(0, 2, n)
    return p


def test_ply_round_trip_exact(tmp_path):
    pts = make_points()
    path = ply_file.write_ply(tmp_path / "a.ply", pts)
    from plyfile import PlyData
    ply = PlyData.read(str(path))
    assert ply.byte_order == "<" and not ply.text
    assert set(ply["vertex"].data.dtype.names) == set(POINT_DTYPE.names)
    back = ply_file.read_ply(path)
    assert back.dtype == POINT_DTYPE
    for name in POINT_DTYPE.names:
        assert np.array_equal(back[name], pts[name]), name


def test_ply_pixel_indices_are_int32_that_point_cloud_tools_keep(tmp_path):
    # Open3D skips ``ushort`` properties ("unsupported datatype"); int32 is kept by Open3D, PCL and
    # CloudCompare. Open3D itself is a 400 MB wheel, so the file is read back with plyfile, a
    # reader independent of the writer's dtype handling, and its declared types are checked.
    pts = make_points(50)
    pts["row"][0], pts["col"][0] = 127, 65535  # the largest index a uint16 could hold survives
    path = ply_file.write_ply(tmp_path / "rc.ply", pts)
    header = path.read_bytes().split(b"end_header")[0].decode("ascii")
    assert "property int row" in header and "property int col" in header and "ushort" not in header
    from plyfile import PlyData
    v = PlyData.read(str(path))["vertex"]
    assert v.data.dtype["row"] == np.dtype("<i4") and v.data.dtype["col"] == np.dtype("<i4")
    assert v["row"].tolist() == pts["row"].tolist() and v["col"].tolist() == pts["col"].tolist()


def test_las_round_trip_extra_bytes_and_scale(tmp_path):
    import laspy
    pts = make_points()
    path = las_file.write_las(tmp_path / "a.las", pts)
    las = laspy.read(str(path))
    assert str(las.header.version) == "1.4"
    assert las.header.point_format.id in (6, 7)
    extra = set(las.point_format.extra_dimension_names)
    assert {"range", "velocity", "snr_db", "row", "col", "valid"} <= extra
    assert np.all(las.header.scales <= 1e-3)   # mm precision or better
    for axis in "xyz":
        err = np.abs(np.asarray(getattr(las, axis)) - pts[axis].astype(np.float64))
        assert err.max() <= las.header.scales[0] / 2 + 1e-12
    back = las_file.read_las(path)
    for name in ("range", "velocity", "snr_db", "intensity", "row", "col", "valid", "return_index", "t"):
        assert np.array_equal(back[name], pts[name]), name
    # number_of_returns counts the returns of the same pixel
    key = pts["row"].astype(int) * 65536 + pts["col"]
    _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    assert np.array_equal(np.asarray(las.number_of_returns), np.minimum(counts[inv], 15))


def test_npz_round_trip_with_meta(tmp_path):
    pts = make_points()
    meta = {"profile": "fpsa128", "simulated": True, "coverage": 0.5}
    path = npz_file.write_npz(tmp_path / "a.npz", pts, meta)
    back, m = npz_file.read_npz(path)
    assert back.dtype == POINT_DTYPE
    assert np.array_equal(back, pts)
    assert m == meta


@pytest.mark.parametrize("fmt", outputs.FORMATS)
def test_empty_cloud_round_trips(tmp_path, fmt):
    pts = np.zeros(0, dtype=POINT_DTYPE)
    files = outputs.write_points(tmp_path / f"e{outputs.suffix_of(fmt)}", pts, {"partial": True})
    back = outputs.read_points(files[0])
    assert len(back) == 0 and back.dtype == POINT_DTYPE
    assert json.loads(files[1].read_text())["points"] == 0


def test_write_points_writes_sidecar(tmp_path):
    pts = make_points(10)
    meta = {"profile": "fpsa20", "simulated": False, "partial": False, "chirp": {"ramp_s": 80e-6}}
    files = outputs.write_points(tmp_path / "s.ply", pts, meta)
    assert files[1].name == "s.ply.json"
    side = outputs.read_sidecar(files[0])
    assert side["profile"] == "fpsa20" and side["simulated"] is False
    assert side["chirp"]["ramp_s"] == 80e-6 and side["points"] == 10 and side["format"] == "ply"


def test_unknown_extension_is_named(tmp_path):
    with pytest.raises(outputs.PointCloudError, match="xyz"):
        outputs.write_points(tmp_path / "a.xyz", make_points(3), {})


def test_atomic_write_leaves_no_partial_file_on_failure(tmp_path):
    target = tmp_path / "x.ply"
    with pytest.raises(RuntimeError):
        with files.atomic_write(target) as f:
            f.write(b"half a file")
            raise RuntimeError("writer died")
    assert os.listdir(tmp_path) == []


def test_atomic_write_failure_keeps_previous_version(tmp_path, monkeypatch):
    target = tmp_path / "x.ply"
    ply_file.write_ply(target, make_points(5))
    before = target.read_bytes()
    from plyfile import PlyData

    def boom(self, stream):
        stream.write(b"ply\nformat binary_little_endian 1.0\n")
        raise OSError("disk full")
    monkeypatch.setattr(PlyData, "write", boom)
    with pytest.raises(OSError, match="disk full"):
        ply_file.write_ply(target, make_points(50))
    assert target.read_bytes() == before
    assert os.listdir(tmp_path) == ["x.ply"]


def test_wrong_dtype_rejected(tmp_path):
    with pytest.raises(outputs.PointCloudError, match="POINT_DTYPE"):
        ply_file.write_ply(tmp_path / "a.ply", np.zeros(3))


def test_written_files_get_ordinary_permissions_not_mkstemps_0600(tmp_path, monkeypatch):
    monkeypatch.setattr(files, "_UMASK", 0o022)
    target = tmp_path / "perm.bin"
    with files.atomic_write(target) as f:
        f.write(b"x")
    assert (target.stat().st_mode & 0o777) == 0o644
    monkeypatch.setattr(files, "_UMASK", 0o077)
    with files.atomic_write(target) as f:
        f.write(b"y")
    assert (target.stat().st_mode & 0o777) == 0o600


@pytest.mark.parametrize("fmt", outputs.FORMATS)
def test_every_format_gives_back_every_field_through_the_dispatch(tmp_path, fmt):
    pts = make_points(64)
    pts["flags"] = np.where(pts["valid"] == 0, 4, 0)
    files = outputs.write_points(tmp_path / f"r{outputs.suffix_of(fmt)}", pts, {"scan_id": "S"})
    assert outputs.format_of(files[0]) == fmt and outputs.read_sidecar(files[0])["format"] == fmt
    back = outputs.read_points(files[0])
    assert back.dtype == POINT_DTYPE and back.flags.writeable
    for name in POINT_DTYPE.names:
        if fmt == "las" and name in "xyz":      # LAS keeps x, y, z as 0.1 mm integers
            assert np.abs(back[name] - pts[name]).max() <= las_file.LAS_SCALE_M / 2 + 1e-6
        else:
            np.testing.assert_array_equal(back[name], pts[name], err_msg=f"{fmt} {name}")
