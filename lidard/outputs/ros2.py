"""MCAP for ROS 2: a rosbag2 file (profile ``ros2``) with ``sensor_msgs/msg/PointCloud2`` in CDR.

The Foxglove flavour (lidard.outputs.mcap: ``foxglove.PointCloud``, protobuf) is what Foxglove and
Lichtblick draw best; ROS 2 tools (``ros2 bag play``/``info``, rosbags, RViz through a player) need
this one: the MCAP profile ``ros2``, schemas in ``ros2msg`` text and messages in CDR.

Topics (frame ``lidar``, the sensor frame of §4.1.1, +z the optical axis):

* ``/lidar/points``: one ``sensor_msgs/msg/PointCloud2`` holding the whole scan, unorganized
  (``height`` 1, ``width`` = points), every field of :data:`lidard.outputs.schema.POINT_FIELDS` as a
  ``PointField`` of its schema dtype, little-endian, ``point_step`` = POINT_DTYPE's itemsize, the data
  POINT_DTYPE's bytes; ``is_dense`` says whether every point is valid.
* ``/lidar/scan_status``: ``std_msgs/msg/String`` holding the JSON summary of lidard.outputs.mcap
  (schema ``lidard.ScanStatus``, lidard.outputs.channels).

The CDR encoder and decoder below cover exactly these two message types (XCDR1, little-endian, the
encoding rmw implementations write); tests read the file back with ``rosbags``.
"""

from __future__ import annotations

import json
import os
import struct
import time
from pathlib import Path
from typing import Any

import numpy as np

from .channels import FRAME_ID, POINTS_TOPIC, STATUS_TOPIC
from .schema import POINT_DTYPE, POINT_FIELDS, POINT_OFFSETS, ROS2_TYPE
from .files import PointCloudError, atomic_write
from .mcap import scan_status

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
STRING = "std_msgs/msg/String"
_SEP = "=" * 80 + "\n"
_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
_POINTFIELD = ("uint8 INT8    = 1\nuint8 UINT8   = 2\nuint8 INT16   = 3\nuint8 UINT16  = 4\n"
               "uint8 INT32   = 5\nuint8 UINT32  = 6\nuint8 FLOAT32 = 7\nuint8 FLOAT64 = 8\n"
               "string name\nuint32 offset\nuint8 datatype\nuint32 count\n")
# ros2msg text as rosbag2 stores it: the type, then each dependency after a separator line
POINTCLOUD2_MSGDEF = ("std_msgs/Header header\nuint32 height\nuint32 width\nsensor_msgs/PointField[] fields\n"
                      "bool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n"
                      f"{_SEP}MSG: std_msgs/Header\n{_HEADER}"
                      f"{_SEP}MSG: builtin_interfaces/Time\n{_TIME}"
                      f"{_SEP}MSG: sensor_msgs/PointField\n{_POINTFIELD}")
STRING_MSGDEF = "string data\n"
_CDR_LE = b"\x00\x01\x00\x00"   # encapsulation: CDR, little-endian


class _Cdr:
    """XCDR1 little-endian writer; alignment counts from after the 4-byte encapsulation header."""

    def __init__(self) -> None:
        self.buf = bytearray(_CDR_LE)

    def _align(self, n: int) -> None:
        self.buf += b"\x00" * (-(len(self.buf) - 4) % n)

    def u8(self, v: int) -> None:
        self.buf += struct.pack("<B", v)

    def u32(self, v: int) -> None:
        self._align(4)
        self.buf += struct.pack("<I", v)

    def i32(self, v: int) -> None:
        self._align(4)
        self.buf += struct.pack("<i", v)

    def string(self, s: str) -> None:
        b = s.encode() + b"\x00"
        self.u32(len(b))
        self.buf += b

    def octets(self, b: bytes) -> None:
        self.u32(len(b))
        self.buf += b


def encode_point_cloud2(points: np.ndarray, time_ns: int, frame_id: str = FRAME_ID) -> bytes:
    pts = np.ascontiguousarray(np.asarray(points).astype(POINT_DTYPE, copy=False))
    w = _Cdr()
    w.i32(int(time_ns // 1_000_000_000))
    w.u32(int(time_ns % 1_000_000_000))
    w.string(frame_id)
    w.u32(1)                       # height: unorganized
    w.u32(len(pts))                # width
    w.u32(len(POINT_FIELDS))
    for f in POINT_FIELDS:
        w.string(f.name)
        w.u32(POINT_OFFSETS[f.name])
        w.u8(ROS2_TYPE[f.dtype])
        w.u32(1)
    w.u8(0)                        # is_bigendian
    w.u32(POINT_DTYPE.itemsize)
    w.u32(POINT_DTYPE.itemsize * len(pts))
    w.octets(pts.tobytes())
    w.u8(int(bool(np.all(pts["valid"] == 1))))  # is_dense: no invalid point
    return bytes(w.buf)


def encode_string(text: str) -> bytes:
    w = _Cdr()
    w.string(text)
    return bytes(w.buf)


def write_ros2_mcap(path: str | os.PathLike, points: np.ndarray, meta: dict[str, Any] | None = None,
                    time_ns: int | None = None) -> Path:
    from mcap.writer import Writer

    meta = meta or {}
    t_ns = time.time_ns() if time_ns is None else int(time_ns)
    with atomic_write(path) as f:
        w = Writer(f)
        w.start(profile="ros2", library="lidard")
        pc2 = w.register_schema(POINTCLOUD2, "ros2msg", POINTCLOUD2_MSGDEF.encode())
        txt = w.register_schema(STRING, "ros2msg", STRING_MSGDEF.encode())
        ch_points = w.register_channel(POINTS_TOPIC, "cdr", pc2)
        ch_status = w.register_channel(STATUS_TOPIC, "cdr", txt)
        w.add_message(ch_points, log_time=t_ns, publish_time=t_ns, data=encode_point_cloud2(points, t_ns))
        status = json.dumps(scan_status(meta, len(points)), sort_keys=True)
        w.add_message(ch_status, log_time=t_ns, publish_time=t_ns, data=encode_string(status))
        w.finish()
    return Path(path)


# ---------------------------------------------------------------------------- reading (tools, tests)
class _CdrReader:
    def __init__(self, data: bytes) -> None:
        if data[:4] != _CDR_LE:
            raise PointCloudError(f"CDR: encapsulation {data[:4].hex()} is not little-endian CDR")
        self.data, self.pos = data, 4

    def _align(self, n: int) -> None:
        self.pos += -(self.pos - 4) % n

    def u8(self) -> int:
        self.pos += 1
        return self.data[self.pos - 1]

    def u32(self) -> int:
        self._align(4)
        self.pos += 4
        return struct.unpack_from("<I", self.data, self.pos - 4)[0]

    def string(self) -> str:
        n = self.u32()
        self.pos += n
        return self.data[self.pos - n:self.pos - 1].decode()

    def octets(self) -> bytes:
        n = self.u32()
        self.pos += n
        return self.data[self.pos - n:self.pos]


_NUMPY_OF_ROS2 = {1: "i1", 2: "u1", 3: "<i2", 4: "<u2", 5: "<i4", 6: "<u4", 7: "<f4", 8: "<f8"}


def decode_point_cloud2(data: bytes) -> np.ndarray:
    """A CDR ``sensor_msgs/msg/PointCloud2`` -> structured array named by its fields."""
    r = _CdrReader(data)
    r.u32(), r.u32(), r.string()              # stamp, frame_id
    height, width = r.u32(), r.u32()
    names, offsets, formats = [], [], []
    for _ in range(r.u32()):
        names.append(r.string())
        offsets.append(r.u32())
        formats.append(_NUMPY_OF_ROS2[r.u8()])
        r.u32()
    if r.u8():
        raise PointCloudError("PointCloud2: big-endian data is not supported")
    step = r.u32()
    r.u32()
    raw = r.octets()
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    return np.frombuffer(raw, dtype=dtype, count=height * width)


def read_ros2_mcap(path: str | os.PathLike) -> np.ndarray:
    """The points of every ``/lidar/points`` PointCloud2 in a ROS 2 MCAP file, concatenated."""
    from mcap.reader import make_reader

    clouds = []
    with open(path, "rb") as f:
        reader = make_reader(f)
        if reader.get_header().profile != "ros2":
            raise PointCloudError(f"{path}: MCAP profile is not ros2 (a Foxglove MCAP file is read as .mcap)")
        for schema, _, message in reader.iter_messages(topics=[POINTS_TOPIC]):
            if schema is None or schema.name != POINTCLOUD2:
                raise PointCloudError(f"{path}: {POINTS_TOPIC} is not a {POINTCLOUD2}")
            clouds.append(decode_point_cloud2(message.data))
    if not clouds:
        raise PointCloudError(f"{path}: no {POINTS_TOPIC} message")
    return np.concatenate(clouds)
