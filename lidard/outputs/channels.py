"""The Foxglove channels lidard publishes, shared by the live server and the MCAP file writer.

Three topics, one per thing a robotics user looks at:

* ``/lidar/points``: ``foxglove.PointCloud`` (protobuf) in frame ``lidar`` (the sensor frame of
  §4.1.1: +z the optical axis). Every field of :data:`lidard.outputs.schema.POINT_FIELDS` (``valid``,
  ``flags`` and ``return_index`` included, so a viewer can filter what the DSP rejected), packed
  little-endian per point in its schema dtype (:data:`PACKED_DTYPE` is POINT_DTYPE).
* ``/lidar/scan_status``: JSON, the worker's progress/end events (``lidard.jobs``) and a stream's
  frame events (one per finished frame, its sidecar), under the JSON schema ``lidard.ScanStatus``
  (:data:`SCAN_STATUS_SCHEMA`).
* ``/lidar/devices``: JSON ``{"devices": [...]}`` as ``GET /devices``, schema ``lidard.DeviceList``.

A :class:`LidarChannels` lives on a ``foxglove.Context``; whatever sinks that context has (a
WebSocket server, an MCAP writer) receive the same messages.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

import foxglove
from foxglove.channels import PointCloudChannel
from foxglove.messages import PackedElementField, PackedElementFieldNumericType, PointCloud, Pose, Quaternion, \
    Timestamp, Vector3

from .schema import FOXGLOVE_TYPE, POINT_DTYPE, POINT_FIELDS, POINT_OFFSETS

FRAME_ID = "lidar"
POINTS_TOPIC, STATUS_TOPIC, DEVICES_TOPIC = "/lidar/points", "/lidar/scan_status", "/lidar/devices"

PACKED_DTYPE = POINT_DTYPE
_NUMERIC = {getattr(PackedElementFieldNumericType, n).value: getattr(PackedElementFieldNumericType, n)
            for n in ("Uint8", "Int8", "Uint16", "Int16", "Uint32", "Int32", "Float32", "Float64")}

_STATUS_KEYS = {
    "event": {"type": "string", "enum": ["progress", "end", "frame"],
              "description": "progress while a scan runs; end once; frame: a stream's frame is complete"},
    "id": {"type": "string", "description": "scan id (live server); a stream's id on its frame and end events"},
    "frame": {"type": "integer", "minimum": 0, "description": "frame index inside a stream (frame events)"},
    "start_s": {"type": "number", "description": "frame: its first trigger, s since the stream's first"},
    "setup_s": {"type": "number", "description": "frame: hardware gap before its first trigger"},
    "valid_points": {"type": "integer", "minimum": 0, "description": "frame: points the DSP kept"},
    "coverage": {"type": "number", "minimum": 0, "maximum": 1, "description": "frame: pixels scanned / planned"},
    "frames": {"type": "integer", "minimum": 0, "description": "stream end: frames kept"},
    "scan_id": {"type": "string", "description": "scan id (MCAP file)"},
    "stage": {"type": "string", "description": "scan stage (linearizing, scanning, ...)"},
    "state": {"type": "string", "description": "final job state (end)"},
    "pixels_done": {"type": "integer", "minimum": 0},
    "pixels_scanned": {"type": ["integer", "null"], "minimum": 0},
    "pixels_planned": {"type": ["integer", "null"], "minimum": 0},
    "points": {"type": "integer", "minimum": 0, "description": "points measured so far"},
    "fraction": {"type": "number", "minimum": 0, "maximum": 1},
    "hardware_time_s": {"type": ["number", "null"], "description": "s of hardware time so far"},
    "partial": {"type": ["boolean", "null"], "description": "the scan stopped before its last pixel"},
    "stop_reason": {"type": ["string", "null"]},
    "error": {"type": ["string", "null"]},
    "calibration_id": {"type": ["string", "null"]},
}
SCAN_STATUS_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema", "title": "lidard.ScanStatus",
    "description": "Progress and end events of a lidard scan", "type": "object",
    "properties": _STATUS_KEYS, "required": ["event"]}
DEVICES_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema", "title": "lidard.DeviceList",
    "description": "State of each instrument (as GET /devices)", "type": "object",
    "properties": {"devices": {"type": "array", "items": {"type": "object"}}}, "required": ["devices"]}


def json_schema(schema: dict[str, Any]) -> foxglove.Schema:
    """A named ``jsonschema`` channel schema (Foxglove shows the name; tools can validate against it)."""
    return foxglove.Schema(name=schema["title"], encoding="jsonschema",
                           data=json.dumps(schema, sort_keys=True).encode())


def packed_fields() -> list[PackedElementField]:
    return [PackedElementField(name=f.name, offset=POINT_OFFSETS[f.name], type=_NUMERIC[FOXGLOVE_TYPE[f.dtype]])
            for f in POINT_FIELDS]


def pack_points(points: np.ndarray) -> bytes:
    """POINT_DTYPE records -> the PointCloud's ``data`` (PACKED_DTYPE rows)."""
    return np.ascontiguousarray(np.asarray(points).astype(PACKED_DTYPE, copy=False)).tobytes()


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
        self.status = foxglove.Channel(STATUS_TOPIC, message_encoding="json", context=context,
                                       schema=json_schema(SCAN_STATUS_SCHEMA))
        self.devices = foxglove.Channel(DEVICES_TOPIC, message_encoding="json", context=context,
                                        schema=json_schema(DEVICES_SCHEMA))

    def log_points(self, points: np.ndarray, time_ns: int) -> None:
        self.points.log(point_cloud(points, time_ns), log_time=int(time_ns))

    def log_status(self, event: dict[str, Any], time_ns: int) -> None:
        self.status.log(event, log_time=int(time_ns))

    def log_devices(self, devices: list[dict[str, Any]], time_ns: int) -> None:
        self.devices.log({"devices": devices}, log_time=int(time_ns))

    def close(self) -> None:
        for ch in (self.points, self.status, self.devices):
            ch.close()
