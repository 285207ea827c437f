"""Opt-in Foxglove live server (``[live] foxglove = true``): the running scan's points, its status and
the devices, on the Foxglove WebSocket protocol (foxglove-sdk), loopback by default.

It is a listener of the scan worker (lidard.jobs): each batch of points the instrument hands over
is one ``/lidar/points`` PointCloud message while the scan runs, and the whole cloud is one message
when it ends (so a Foxglove panel ends on the complete frame, like Fig. 4-35); a stream's frame is
one ``/lidar/points`` message as soon as it is complete (its points carry the frame index), followed
by its ``frame`` event (the frame's sidecar) on ``/lidar/scan_status``; every progress/end
event is a ``/lidar/scan_status`` message; after each scan ``/lidar/devices`` carries the device
list (as ``GET /devices``). Topics and encodings: lidard.outputs.channels (the MCAP writer uses the
same). The server has its own foxglove Context, so several daemons (tests) never share channels.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np

import foxglove

from ..outputs.channels import LidarChannels

log = logging.getLogger(__name__)


class FoxgloveLive:
    def __init__(self, host: str = "127.0.0.1", port: int = 8765,
                 devices: Callable[[], list[dict[str, Any]]] | None = None, name: str = "lidard"):
        self.context = foxglove.Context()
        self.channels = LidarChannels(self.context)  # advertised before any client connects
        self._devices = devices
        self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context)
        log.info("foxglove live server on ws://%s:%d", host, self.server.port)

    @property
    def port(self) -> int:
        return self.server.port

    def on_points(self, scan_id: str, points: np.ndarray, final: bool) -> None:
        """Worker point listener: a batch, or the final cloud."""
        if self.channels.points.has_sinks():  # packing costs; skip it when nobody listens
            self.channels.log_points(points, time.time_ns())

    def on_event(self, event: dict[str, Any]) -> None:
        """Worker event listener: progress and end of every scan."""
        now = time.time_ns()
        self.channels.log_status(event, now)
        if event.get("event") == "end" and self._devices is not None:
            try:
                self.channels.log_devices(self._devices(), now)
            except Exception as exc:  # a device check must not break the scan's end
                log.warning("foxglove: device status unavailable: %s", exc)

    def close(self) -> None:
        try:
            self.server.stop()
        finally:
            self.channels.close()
