"""Every point file read back with a reader lidard did not write (plyfile, laspy, mcap + protobuf from the
file's own descriptor set, rosbags, a PCD header parse), each field and its type checked against the
one schema, lidard.outputs.schema."""

import json

import numpy as np
import pytest

from lidard import outputs
from lidard.outputs import las as las_file
from lidard.outputs import npz as npz_file
from lidard.outputs import ply as ply_file
from lidard.outputs.schema import (FOXGLOVE_TYPE, LAS_EXTRA_FIELDS, PCD_TYPE, POINT_DTYPE, POINT_FIELDS, ROS2_TYPE,
                                 las_extra_name)

T_NS = 1_700_000_000_123_456_789


def cloud(n=300, seed=11):
    rng = np.random.default_rng(seed)
    p = np.zeros(n, POINT_DTYPE)
    p["x"], p["y"] = rng.uniform(-0.4, 0.4, n), rng.uniform(-0.4, 0.4, n)
    p["z"] = rng.uniform(0.5, 5.0, n)
    p["range"] = np.sqrt(p["x"].astype(float) ** 2 + p["y"] ** 2 + p["z"] ** 2)
    p["velocity"] = rng.normal(0, 1.5, n)
    p["intensity"] = rng.uniform(1e-3, 0.4, n)
    p["snr_db"] = rng.uniform(6, 40, n)
    p["row"], p["col"] = rng.integers(0, 128, n), rng.integers(0, 128, n)
    p["row"][0], p["col"][0] = 70_000, 2**31 - 1    # beyond uint16: int32 everywhere keeps it
    p["return_index"] = rng.integers(0, 3, n)
    p["t"] = np.sort(rng.uniform(0, 2.0, n)) + 1e-9
    p["valid"] = (rng.uniform(size=n) > 0.1).astype(np.uint8)
    p["flags"] = np.where(p["valid"] == 0, rng.choice([1, 2, 4, 8, 16], n), 0)
    return p


def assert_fields_exact(got, pts, names=None):
    for f in POINT_FIELDS:
        if names is not None and f.name not in names:
            continue
        assert got[f.name].dtype == np.dtype(f.dtype), f.name
        np.testing.assert_array_equal(got[f.name], pts[f.name], err_msg=f.name)


def test_schema_is_the_in_memory_record_and_row_col_are_int32():
    assert POINT_DTYPE.names == tuple(f.name for f in POINT_FIELDS)
    assert POINT_DTYPE["row"] == POINT_DTYPE["col"] == np.dtype("<i4")
    assert {"valid", "flags", "return_index"} <= set(POINT_DTYPE.names)


def test_ply_plyfile(tmp_path):
    from plyfile import PlyData
    pts = cloud()
    path = ply_file.write_ply(tmp_path / "a.ply", pts)
    header = path.read_bytes().split(b"end_header")[0].decode("ascii").splitlines()
    assert "format binary_little_endian 1.0" in header
    props = [ln.split()[1:] for ln in header if ln.startswith("property ")]
    ply_types = {"float": "<f4", "double": "<f8", "int": "<i4", "uchar": "u1"}   # the PLY spec's names
    assert [(name, ply_types[typ]) for typ, name in props] == [(f.name, f.dtype) for f in POINT_FIELDS]
    assert_fields_exact(PlyData.read(str(path))["vertex"].data, pts)


def test_pcd_header_and_records(tmp_path):
    from lidard.outputs.pcd import write_pcd
    pts = cloud()
    raw = write_pcd(tmp_path / "a.pcd", pts).read_bytes()
    header, _, body = raw.partition(b"DATA binary\n")
    h = {ln.split()[0]: ln.split()[1:] for ln in header.decode().splitlines() if not ln.startswith("#")}
    assert h["FIELDS"] == [f.name for f in POINT_FIELDS]
    assert list(zip(h["TYPE"], map(int, h["SIZE"]))) == [PCD_TYPE[f.dtype] for f in POINT_FIELDS]
    # the records as PCL reads them: packed, in header order, sizes from SIZE, kinds from TYPE
    kinds = {"F": "f", "I": "i", "U": "u"}
    dt = np.dtype([(n, f"<{kinds[t]}{s}") for n, t, s in zip(h["FIELDS"], h["TYPE"], h["SIZE"])])
    assert_fields_exact(np.frombuffer(body, dt), pts)


def test_las_laspy_noise_withheld_intensity_and_extra_bytes(tmp_path):
    import laspy
    pts = cloud()
    path = las_file.write_las(tmp_path / "a.las", pts)
    las = laspy.read(str(path))
    invalid = pts["valid"] == 0
    assert invalid.any() and (~invalid).any()
    cls = np.asarray(las.classification)
    assert np.all(cls[invalid] == 7) and np.all(cls[~invalid] == 1)     # ASPRS 7 = low point (noise)
    assert np.array_equal(np.asarray(las.withheld).astype(bool), invalid)
    # intensity: linear in the amplitude, peak at half scale (none saturated), the scale in the VLR
    inten = np.asarray(las.intensity).astype(float)
    assert inten.max() == 32767 and inten.max() < 65535
    vlr = next(v for v in las.header.vlrs if v.user_id == "lidard" and v.record_id == 1)
    vpc = json.loads(vlr.record_data)["intensity_volts_per_count"]
    np.testing.assert_allclose(inten * vpc, pts["intensity"], atol=vpc / 2 + 1e-12)
    # every extra byte is a schema field of the schema's dtype, described with its unit
    extra = {d.name: d for d in las.point_format.extra_dimensions}
    assert set(extra) == {las_extra_name(n) for n in LAS_EXTRA_FIELDS}
    by_name = {f.name: f for f in POINT_FIELDS}
    for name in LAS_EXTRA_FIELDS:
        got = np.asarray(las[las_extra_name(name)])
        assert got.dtype == np.dtype(by_name[name].dtype), name
        np.testing.assert_array_equal(got, pts[name], err_msg=name)
        unit = by_name[name].unit
        assert (f"[{unit}]" in extra[las_extra_name(name)].description) == bool(unit)
    np.testing.assert_array_equal(np.asarray(las.gps_time), pts["t"])
    np.testing.assert_array_equal(np.asarray(las.return_number), pts["return_index"] + 1)
    for axis in "xyz":
        assert np.abs(np.asarray(las[axis]) - pts[axis]).max() <= 0.5e-4 + 1e-9


def test_npz_numpy(tmp_path):
    pts = cloud()
    path = npz_file.write_npz(tmp_path / "a.npz", pts, {"k": 1})
    with np.load(path, allow_pickle=False) as z:
        assert_fields_exact(z["points"], pts)


def _protobuf_class(schema):
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def test_mcap_foxglove_point_cloud_via_protobuf_and_json_schemas(tmp_path):
    from mcap.reader import make_reader

    from lidard.outputs.mcap import write_mcap
    pts = cloud()
    path = write_mcap(tmp_path / "a.mcap", pts, {"scan_id": "S", "partial": False,
                                                 "devices": [{"name": "fpsa", "state": "ready"}]}, time_ns=T_NS)
    with open(path, "rb") as f:
        msgs = list(make_reader(f).iter_messages())
    by_topic = {ch.topic: (sc, m) for sc, ch, m in msgs}
    schema, m = by_topic["/lidar/points"]
    assert schema.encoding == "protobuf"
    msg = _protobuf_class(schema).FromString(m.data)
    assert msg.frame_id == "lidar" and msg.point_stride == POINT_DTYPE.itemsize
    numeric = {1: "u1", 2: "i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<f4", 8: "<f8"}
    assert [fl.name for fl in msg.fields] == [f.name for f in POINT_FIELDS]
    for fl, f in zip(msg.fields, POINT_FIELDS):
        assert fl.type == FOXGLOVE_TYPE[f.dtype] and numeric[fl.type] == f.dtype, f.name
    dt = np.dtype({"names": [fl.name for fl in msg.fields], "formats": [numeric[fl.type] for fl in msg.fields],
                   "offsets": [fl.offset for fl in msg.fields], "itemsize": msg.point_stride})
    assert_fields_exact(np.frombuffer(msg.data, dt), pts)
    # status topics: a named, non-empty JSON schema that their messages satisfy
    import jsonschema
    for topic, name in (("/lidar/scan_status", "lidard.ScanStatus"), ("/lidar/devices", "lidard.DeviceList")):
        sc, m = by_topic[topic]
        assert sc.name == name and sc.encoding == "jsonschema"
        jsonschema.validate(json.loads(m.data), json.loads(sc.data))
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"event": "begin"}, json.loads(by_topic["/lidar/scan_status"][0].data))


def test_ros2_mcap_rosbags(tmp_path):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from lidard.outputs.ros2 import write_ros2_mcap
    pts = cloud()
    files = [write_ros2_mcap(tmp_path / "a.ros2.mcap", pts, {"scan_id": "S", "partial": True}, time_ns=T_NS)]
    assert outputs.format_of(files[0]) == "ros2" and outputs.suffix_of("ros2") == ".ros2.mcap"
    store = get_typestore(Stores.EMPTY)
    with Reader(files[0]) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert conns["/lidar/points"].msgtype == "sensor_msgs/msg/PointCloud2"
        assert conns["/lidar/scan_status"].msgtype == "std_msgs/msg/String"
        for c in conns.values():   # the file's own ros2msg definitions parse
            store.register(get_types_from_msg(c.msgdef.data, c.msgtype))
        got = {c.topic: (t, store.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()}
    t, cloud2 = got["/lidar/points"]
    assert t == T_NS and cloud2.header.stamp.sec * 10**9 + cloud2.header.stamp.nanosec == T_NS
    assert cloud2.header.frame_id == "lidar" and cloud2.height == 1 and cloud2.width == len(pts)
    assert not cloud2.is_bigendian and cloud2.point_step == POINT_DTYPE.itemsize
    assert cloud2.is_dense is False   # some points are invalid
    ros = {1: "i1", 2: "u1", 3: "<i2", 4: "<u2", 5: "<i4", 6: "<u4", 7: "<f4", 8: "<f8"}
    assert [fl.name for fl in cloud2.fields] == [f.name for f in POINT_FIELDS]
    for fl, f in zip(cloud2.fields, POINT_FIELDS):
        assert fl.datatype == ROS2_TYPE[f.dtype] and ros[fl.datatype] == f.dtype and fl.count == 1, f.name
    dt = np.dtype({"names": [fl.name for fl in cloud2.fields], "formats": [ros[fl.datatype] for fl in cloud2.fields],
                   "offsets": [fl.offset for fl in cloud2.fields], "itemsize": cloud2.point_step})
    assert_fields_exact(np.frombuffer(bytes(cloud2.data), dt), pts)
    status = json.loads(got["/lidar/scan_status"][1].data)
    assert status["event"] == "end" and status["scan_id"] == "S" and status["points"] == len(pts)
    # lidard's own reader agrees, through the format dispatch, which writes the sidecar too
    files = outputs.write_points(tmp_path / "b.ros2.mcap", pts, {"scan_id": "S"})
    assert files[1].name == "b.ros2.mcap.json" and outputs.read_sidecar(files[0])["format"] == "ros2"
    assert_fields_exact(outputs.read_points(files[0]), pts)


def test_foxglove_mcap_is_not_taken_for_ros2(tmp_path):
    from lidard.outputs.ros2 import read_ros2_mcap
    pts = cloud(5)
    outputs.write_points(tmp_path / "f.mcap", pts, {})
    with pytest.raises(outputs.PointCloudError, match="profile is not ros2"):
        read_ros2_mcap(tmp_path / "f.mcap")
