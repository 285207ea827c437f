"""A stream's frames in one MCAP file (Foxglove flavour, as lidard.outputs.mcap): one ``/lidar/points``
PointCloud and one ``/lidar/scan_status`` JSON message (the frame's sidecar) per frame, logged at the
frame's time (the stream's wall-clock start plus the frame's hardware start). The file is written to
a temporary name and renamed on :meth:`McapFrameWriter.close`, so a stopped stream leaves a complete
file of the frames it finished (and its partial last frame), never a truncated one.
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path
from typing import Any

import foxglove
import numpy as np

from .channels import LidarChannels
from .files import atomic_write


class McapFrameWriter:
    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._stack = contextlib.ExitStack()
        f = self._stack.enter_context(atomic_write(self.path))
        self._ctx = foxglove.Context()
        self._writer = foxglove.open_mcap(f, context=self._ctx)
        self._channels = LidarChannels(self._ctx)
        self._t0_ns = time.time_ns()
        self.frames = 0

    def add(self, points: np.ndarray, sidecar: dict[str, Any]) -> None:
        t_ns = self._t0_ns + int(round(float(sidecar.get("start_s", 0.0)) * 1e9))
        self._channels.log_points(points, t_ns)
        self._channels.log_status({"event": "frame", **sidecar}, t_ns)
        self.frames += 1

    def close(self) -> Path:
        try:
            self._writer.close()
        finally:
            self._stack.close()
        return self.path
