"""The Foxglove channels lidard publishes, shared by the live server and the MCAP file writer.

Three topics, one per thing a robotics user looks at (issue 16 item 2):

* ``/lidar/points``: ``foxglove.PointCloud`` (protobuf) in frame ``lidar`` (the sensor frame of
  §4.1.1: +z the optical axis). Fields, packed little-endian per point (:data:`PACKED_DTYPE`):
  x, y, z, range, velocity, intensity, snr_db (float32), row, col (int32), t (float64, s from the
  scan's start, the pixel's hardware trigger time).
* ``/lidar/scan_status``: JSON, the worker's progress/end events (``lidard.jobs``).
* ``/lidar/devices``: JSON ``{"devices": [...]}`` as ``GET /devices``.

A :class:`LidarChannels` lives on a ``foxglove.Context``; whatever sinks that context has (a
WebSocket server, an MCAP writer) receive the same messages.
"""

from __future__ import annotations

from typing import Any

import numpy as np

import foxglove
from foxglove.channels import PointCloudChannel
from foxglove.messages import PackedElementField, PackedElementFieldNumericType, PointCloud, Pose, Quaternion, \
    Timestamp, Vector3

FRAME_ID = "lidar"
POINTS_TOPIC, STATUS_TOPIC, DEVICES_TOPIC = "/lidar/points", "/lidar/scan_status", "/lidar/devices"

_F32, _I32, _F64 = "<f4", "<i4", "<f8"
PACKED_DTYPE = np.dtype([("x", _F32), ("y", _F32), ("z", _F32), ("range", _F32), ("velocity", _F32),
                         ("intensity", _F32), ("snr_db", _F32), ("row", _I32), ("col", _I32), ("t", _F64)])
_NUMERIC = {_F32: PackedElementFieldNumericType.Float32, _I32: PackedElementFieldNumericType.Int32,
            _F64: PackedElementFieldNumericType.Float64}


def packed_fields() -> list[PackedElementField]:
    return [PackedElementField(name=name, offset=PACKED_DTYPE.fields[name][1],
                               type=_NUMERIC[PACKED_DTYPE.fields[name][0].str])
            for name in PACKED_DTYPE.names]


def pack_points(points: np.ndarray) -> bytes:
    """POINT_DTYPE records -> the PointCloud's ``data`` (PACKED_DTYPE rows)."""
    out = np.zeros(len(points), PACKED_DTYPE)
    for name in PACKED_DTYPE.names:
        out[name] = points[name]
    return out.tobytes()


def stamp(time_ns: int) -> Timestamp:
    return Timestamp(sec=int(time_ns // 1_000_000_000), nsec=int(time_ns % 1_000_000_000))


def point_cloud(points: np.ndarray, time_ns: int) -> PointCloud:
    identity = Pose(position=Vector3(x=0, y=0, z=0), orientation=Quaternion(x=0, y=0, z=0, w=1))
    return PointCloud(timestamp=stamp(time_ns), frame_id=FRAME_ID, pose=identity,
                      point_stride=PACKED_DTYPE.itemsize, fields=packed_fields(), data=pack_points(points))


class LidarChannels:
    """The three topics on one context (the global one when ``context`` is None)."""

    def __init__(self, context: foxglove.Context | None = None):
        self.points = PointCloudChannel(POINTS_TOPIC, context=context)
        self.status = foxglove.Channel(STATUS_TOPIC, message_encoding="json", context=context)
        self.devices = foxglove.Channel(DEVICES_TOPIC, message_encoding="json", context=context)

    def log_points(self, points: np.ndarray, time_ns: int) -> None:
        self.points.log(point_cloud(points, time_ns), log_time=int(time_ns))

    def log_status(self, event: dict[str, Any], time_ns: int) -> None:
        self.status.log(event, log_time=int(time_ns))

    def log_devices(self, devices: list[dict[str, Any]], time_ns: int) -> None:
        self.devices.log({"devices": devices}, log_time=int(time_ns))

    def close(self) -> None:
        for ch in (self.points, self.status, self.devices):
            ch.close()
