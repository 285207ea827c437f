"""MCAP output, Foxglove flavour: a scan as the Foxglove topics of lidard.outputs.channels, in one file
that Foxglove and Lichtblick open (profile none, ``foxglove.PointCloud`` in protobuf, JSON status under
named JSON schemas). ROS 2 tools (``ros2 bag``, rosbags) need the ``ros2`` format instead
(lidard.outputs.ros2: ``sensor_msgs/msg/PointCloud2`` in CDR).

``write_mcap`` logs the whole cloud as one ``/lidar/points`` PointCloud (every point; ``t`` keeps
the per-pixel hardware time of §4.4's scan), one ``/lidar/scan_status`` JSON summary and, when the
metadata carries them, ``/lidar/devices``. It goes through foxglove-sdk's MCAP writer on a private
context (nothing leaks to a live server) into lidard.outputs.files' atomic temp-file-then-rename.

``read_mcap`` reads it back with the ``mcap`` package's reader and decodes the PointCloud's
protobuf by hand (no protobuf runtime needed), honouring the field table in the file; tests decode
the same message with protobuf from the descriptor set the file carries.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

import foxglove
from mcap.reader import make_reader

from .channels import POINTS_TOPIC, STATUS_TOPIC, LidarChannels
from .files import PointCloudError, atomic_write

_NUMPY_OF_FOXGLOVE = {1: "<u1", 2: "<i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<f4", 8: "<f8"}


def scan_status(meta: dict[str, Any], points: int) -> dict[str, Any]:
    keys = ("scan_id", "partial", "pixels_scanned", "pixels_planned", "hardware_time_s", "stop_reason",
            "calibration_id")
    return {"event": "end", **{k: meta.get(k) for k in keys}, "points": int(points)}


def write_mcap(path: str | os.PathLike, points: np.ndarray, meta: dict[str, Any] | None = None,
               time_ns: int | None = None) -> Path:
    meta = meta or {}
    t_ns = time.time_ns() if time_ns is None else int(time_ns)
    ctx = foxglove.Context()
    with atomic_write(path) as f:
        writer = foxglove.open_mcap(f, context=ctx)
        channels = LidarChannels(ctx)
        channels.log_points(points, t_ns)
        channels.log_status(scan_status(meta, len(points)), t_ns)
        if meta.get("devices"):
            channels.log_devices(meta["devices"], t_ns)
        writer.close()
    return Path(path)


# ---------------------------------------------------------------------------- reading (tests, tools)
def _varint(buf: bytes, i: int) -> tuple[int, int]:
    out = shift = 0
    while True:
        b = buf[i]
        i += 1
        out |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            return out, i


def _fields(buf: bytes) -> list[tuple[int, Any]]:
    """Top-level protobuf fields as (number, value): varints as int, length-delimited as bytes."""
    out, i = [], 0
    while i < len(buf):
        key, i = _varint(buf, i)
        num, wire = key >> 3, key & 7
        val: int | bytes
        if wire == 0:
            val, i = _varint(buf, i)
        elif wire == 1:
            val, i = buf[i:i + 8], i + 8
        elif wire == 5:
            val, i = int.from_bytes(buf[i:i + 4], "little"), i + 4
        elif wire == 2:
            n, i = _varint(buf, i)
            val, i = buf[i:i + n], i + n
        else:
            raise PointCloudError(f"MCAP PointCloud: unsupported protobuf wire type {wire}")
        out.append((num, val))
    return out


def decode_point_cloud(message: bytes) -> np.ndarray:
    """A ``foxglove.PointCloud`` protobuf message -> structured array with its packed fields."""
    stride, data, names, formats, offsets = 0, b"", [], [], []
    for num, val in _fields(message):
        if num == 4:      # point_stride (fixed32)
            stride = int(val)
        elif num == 5:    # PackedElementField {name=1, offset=2 (fixed32), type=3}
            f = dict(_fields(val))
            names.append(f[1].decode())
            offsets.append(int(f.get(2, 0)))
            formats.append(_NUMPY_OF_FOXGLOVE[int(f.get(3, 0))])
        elif num == 6:
            data = val
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": stride})
    return np.frombuffer(data, dtype=dtype)


def read_mcap(path: str | os.PathLike) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """The points of every ``/lidar/points`` message (concatenated) and the status messages."""
    clouds, statuses = [], []
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=[POINTS_TOPIC, STATUS_TOPIC]):
            if channel.topic == POINTS_TOPIC:
                if schema is None or schema.name != "foxglove.PointCloud":
                    raise PointCloudError(f"{path}: {POINTS_TOPIC} is not a foxglove.PointCloud")
                clouds.append(decode_point_cloud(message.data))
            else:
                statuses.append(json.loads(message.data))
    if not clouds:
        raise PointCloudError(f"{path}: no {POINTS_TOPIC} message")
    return np.concatenate(clouds), statuses
