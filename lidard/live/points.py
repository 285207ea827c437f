"""The points of recent scans as they are measured, for clients that watch a scan grow.

The scan worker (lidard.jobs) hands every batch of points it learns of to its point listeners; a
:class:`LivePoints` is one of them. It keeps, per scan, the points in the order they were measured
(the order of the final cloud, §4.4: pixel by pixel along the scan pattern), so a client that has
``n`` points asks for ``since=n`` and gets exactly the rest. When the scan ends the final cloud
replaces the buffer (it is the authority: the instrument may hand over no batches at all, or the
adaptive pass shifts ``t``), and the scan is marked complete. Only the newest ``keep`` scans stay
in memory; older ones are read back from their files by the API.

:func:`encode_points` is the wire format of ``GET /scans/{id}/points/live``: little-endian float32,
``len(LIVE_FIELDS)`` values per point, because a browser turns that into a ``Float32Array`` without
parsing (row/col are exact in float32; ``t`` keeps microseconds over the scans lidard makes).
"""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass

import numpy as np

LIVE_FIELDS = ("x", "y", "z", "range", "velocity", "intensity", "snr_db", "row", "col", "t", "valid")


@dataclass(frozen=True)
class LiveSlice:
    points: np.ndarray   # POINT_DTYPE records from ``start`` on
    start: int           # index of the first record in the scan's cloud
    total: int           # points known so far
    complete: bool       # the scan ended: ``total`` is final


class LivePoints:
    """Thread-safe per-scan point buffers (the worker thread writes, API requests read)."""

    def __init__(self, keep: int = 4):
        if keep < 1:
            raise ValueError(f"LivePoints keep must be >= 1, got {keep!r}")
        self.keep = int(keep)
        self._chunks: collections.OrderedDict[str, list[np.ndarray]] = collections.OrderedDict()
        self._complete: dict[str, bool] = {}
        self._lock = threading.Lock()

    def _slot(self, scan_id: str) -> list[np.ndarray]:
        # called with the lock held; the newest scans win the memory
        if scan_id not in self._chunks:
            self._chunks[scan_id] = []
            self._complete[scan_id] = False
            while len(self._chunks) > self.keep:
                old, _ = self._chunks.popitem(last=False)
                self._complete.pop(old, None)
        return self._chunks[scan_id]

    def __call__(self, scan_id: str, points: np.ndarray, final: bool) -> None:
        """The worker's point-listener signature: a batch (``final=False``) or the whole cloud."""
        if final:
            self.finish(scan_id, points)
        else:
            self.append(scan_id, points)

    def append(self, scan_id: str, batch: np.ndarray) -> None:
        with self._lock:
            if not self._complete.get(scan_id, False) and len(batch):
                self._slot(scan_id).append(np.array(batch, copy=True))

    def finish(self, scan_id: str, points: np.ndarray) -> None:
        with self._lock:
            slot = self._slot(scan_id)
            slot[:] = [np.array(points, copy=True)]
            self._complete[scan_id] = True

    def knows(self, scan_id: str) -> bool:
        with self._lock:
            return scan_id in self._chunks

    def since(self, scan_id: str, start: int) -> LiveSlice | None:
        """The points from index ``start`` on, or None when the scan is not buffered."""
        with self._lock:
            if scan_id not in self._chunks:
                return None
            chunks = list(self._chunks[scan_id])
            complete = self._complete[scan_id]
        pts = np.concatenate(chunks) if chunks else None
        total = 0 if pts is None else len(pts)
        start = min(max(0, int(start)), total)
        return LiveSlice(pts[start:] if pts is not None else np.zeros(0), start, total, complete)


def encode_points(points: np.ndarray) -> bytes:
    """``len(points) * len(LIVE_FIELDS)`` little-endian float32 values, point-major."""
    out = np.empty((len(points), len(LIVE_FIELDS)), dtype="<f4")
    for i, name in enumerate(LIVE_FIELDS):
        out[:, i] = points[name] if len(points) else 0
    return out.tobytes()


def decode_points(data: bytes) -> dict[str, np.ndarray]:
    """Inverse of :func:`encode_points` (for tests and Python clients): field -> float32 column."""
    arr = np.frombuffer(data, dtype="<f4").reshape(-1, len(LIVE_FIELDS))
    return {name: arr[:, i] for i, name in enumerate(LIVE_FIELDS)}
