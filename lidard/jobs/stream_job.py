"""A stream as a job of the scan worker: the linearization it uses, its planner, where its frames go.

A stream runs on the worker's thread (:meth:`lidard.jobs.worker.ScanWorker.submit_task`), so it
owns the instrument as a scan does and scans queued meanwhile wait for it. Before the first frame
the worker's linearization policy runs (stored calibration, health check, re-linearization:
:meth:`ScanWorker.current_linearization`); between frames the stream repeats the check
(:mod:`lidard.instrument.stream`). Frames are written as they finish:

* ``out`` a directory: ``frame_NNNNN.<fmt>`` with its JSON sidecar per frame (frame index, start,
  hardware time, set-up gap, pixels, coverage, the planner's trade);
* ``out`` a ``.mcap`` file: one PointCloud and one status message per frame
  (:mod:`lidard.outputs.mcap_stream`), the file closed (renamed into place) when the stream ends.

A stop (``cancel``: DELETE, Ctrl-C, SIGTERM) ends the frame in progress: it is kept as a partial
frame after every finished one.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..instrument.types import ScanRequest

log = logging.getLogger("lidard.jobs")

STREAM_PATTERNS = ("raster", "serpentine", "roi", "pixels", "track")
# frames whose points a stream keeps in memory for live clients (a few MB at the sizes lidard streams);
# older frames are read back from their files
KEEP_FRAMES = 32


class StreamRequestError(ValueError):
    """A stream request that cannot run; the message names the field."""


@dataclasses.dataclass
class StreamSpec:
    request: ScanRequest
    frames: int | None = None             # None: until stopped
    frame_rate_hz: float | None = None    # the track pattern's pixel budget
    out: str | None = None                # a directory (frames in request.formats[0]) or a .mcap file
    health_interval_s: float = 60.0
    # hardware time of one pixel (lidard.instrument.frames.pixel_period_s of the configuration): the
    # unit of the track pattern's pixel budget
    pixel_s: float | None = None

    def check(self) -> None:
        pat = self.request.pattern
        if pat not in STREAM_PATTERNS:
            raise StreamRequestError(f"pattern: {pat!r} cannot stream; allowed: {', '.join(STREAM_PATTERNS)} "
                                     "(adaptive is a two-pass scan: its streaming form is track)")
        if self.frames is not None and self.frames < 1:
            raise StreamRequestError(f"frames: {self.frames} must be >= 1 (leave it out to stream until stopped)")
        if self.frame_rate_hz is not None and not self.frame_rate_hz > 0:
            raise StreamRequestError(f"frame_rate_hz: {self.frame_rate_hz} must be > 0")
        if self.frame_rate_hz is not None and pat != "track":
            raise StreamRequestError("frame_rate_hz: only the track pattern plans its frames to a frame rate; "
                                     f"a {pat!r} frame takes as long as its pixels")
        if not self.health_interval_s > 0:
            raise StreamRequestError(f"health_interval_s: {self.health_interval_s} must be > 0")
        if pat == "track" and not (self.pixel_s is not None and self.pixel_s > 0):
            raise StreamRequestError(f"pixel_s: the track pattern needs the hardware time of one pixel, got "
                                     f"{self.pixel_s!r}")


def planner_for(spec: StreamSpec, optics) -> Callable:
    """The frame planner of a stream: the same pixels every frame, or the track planner."""
    from ..instrument.frames import FramePlan
    from ..instrument.plan import plan
    req = spec.request
    if req.pattern == "track":
        from ..instrument.tracking import TrackParams, track_planner
        spec.check()
        assert spec.pixel_s is not None     # check() refuses a track stream without it
        return track_planner(req, optics, TrackParams(frame_rate_hz=spec.frame_rate_hz or 10.0,
                                                      pixel_s=spec.pixel_s))
    px = plan(req, optics)
    trade = {"pattern": req.pattern, "pixels": len(px)}
    return lambda k, history: FramePlan(px, trade)


def frame_id(stream_id: str, index: int) -> str:
    """The id a stream's frame goes by for the live point listeners (one complete cloud each)."""
    return f"{stream_id}-f{index:05d}"


class FrameSink:
    """Writes each frame where ``out`` says (nothing without ``out``)."""

    def __init__(self, out: str | None, fmt: str, meta: dict[str, Any]):
        self.meta = meta
        self.written: list[str] = []
        self._mcap = None
        self._dir: Path | None = None
        self.fmt = fmt
        if out is None:
            return
        if str(out).endswith(".mcap"):
            from ..outputs.mcap_stream import McapFrameWriter
            Path(out).parent.mkdir(parents=True, exist_ok=True)
            self._mcap = McapFrameWriter(out)
        else:
            self._dir = Path(out)
            self._dir.mkdir(parents=True, exist_ok=True)

    def add(self, frame) -> None:
        side = frame.sidecar()
        if self._mcap is not None:
            self._mcap.add(frame.points, side)
        elif self._dir is not None:
            from ..outputs import suffix_of, write_points
            path = self._dir / f"frame_{frame.index:05d}{suffix_of(self.fmt)}"
            write_points(path, frame.points, {**self.meta, **side}, self.fmt)
            self.written.append(str(path))

    def close(self) -> None:
        if self._mcap is not None:
            self.written.append(str(self._mcap.close()))
            self._mcap = None


@dataclasses.dataclass
class StreamJob:
    """One stream's state, readable from any thread (GET /streams/{id})."""

    spec: StreamSpec
    id: str = dataclasses.field(default_factory=lambda: uuid.uuid4().hex[:12])
    cancel: threading.Event = dataclasses.field(default_factory=threading.Event)
    done: threading.Event = dataclasses.field(default_factory=threading.Event)
    state: str = "queued"                  # queued | running | done | stopped | failed
    frames: list[dict[str, Any]] = dataclasses.field(default_factory=list)   # the sidecars so far
    stop_reason: str | None = None
    error: str | None = None
    files: list[str] = dataclasses.field(default_factory=list)
    linearization: dict | None = None
    started_at: float | None = None
    on_frame: Callable[[Any], None] | None = None      # live listeners (the frame object)
    # the newest frames' points by index (the web viewer animates them; older ones are read from their
    # files): at most ``keep_frames``
    recent: dict[int, Any] = dataclasses.field(default_factory=dict)
    keep_frames: int = KEEP_FRAMES
    created_at: float = dataclasses.field(default_factory=time.time)

    def frame_points(self, index: int):
        """Frame ``index``'s points when still held in memory, else None."""
        return self.recent.get(int(index))

    def status(self) -> dict[str, Any]:
        return {"id": self.id, "state": self.state, "created_at": self.created_at, "frames_done": len(self.frames),
                "frames_planned": self.spec.frames, "pattern": self.spec.request.pattern,
                "frame_rate_hz": self.spec.frame_rate_hz, "out": self.spec.out, "stop_reason": self.stop_reason,
                "error": self.error, "files": list(self.files), "linearization": self.linearization,
                "last_frame": self.frames[-1] if self.frames else None}

    def run(self, worker, meta: dict[str, Any] | None = None) -> dict[str, Any]:
        """On the worker thread: linearization policy, then frames until done or stopped."""
        from ..instrument.errors import describe_failure
        inst = worker.instrument
        self.state, self.started_at = "running", time.time()
        sink = None
        try:
            cal = worker.current_linearization(request=self.spec.request)
            self.linearization = worker.last_linearization
            sink = FrameSink(self.spec.out, self.spec.request.formats[0], dict(meta or {}))
            planner = planner_for(self.spec, worker.optics)

            def frame_done(frame) -> None:
                sink.add(frame)
                side = frame.sidecar()
                self.recent[frame.index] = frame.points
                for old in [k for k in self.recent if k <= frame.index - self.keep_frames]:
                    del self.recent[old]
                self.frames.append(side)
                # live: each frame as one complete cloud (web viewer, Foxglove) and a "frame" event
                # (Foxglove's status topic, subscribers of the stream's id)
                events = getattr(worker, "events", None)
                if events is not None:
                    events.points_out(frame_id(self.id, frame.index), frame.points, True)
                    events.publish(self.id, {"event": "frame", "id": self.id, **side})
                if self.on_frame is not None:
                    self.on_frame(frame)

            res = inst.run_stream(self.spec.request, planner, frame_done, self.cancel, cal,
                                  frames=self.spec.frames, health_interval_s=self.spec.health_interval_s)
            self.stop_reason = res.stop_reason
            self.state = "stopped" if (res.cancelled or res.stop_reason) else "done"
            return {"frames": res.frames, "hardware_time_s": res.hardware_time_s, "health": res.health,
                    **res.meta}
        except Exception as exc:
            self.state, self.error = "failed", describe_failure(exc)
            raise
        finally:
            try:
                if sink is not None:
                    try:
                        sink.close()
                    finally:
                        self.files = list(sink.written)
            finally:
                events = getattr(worker, "events", None)
                if events is not None:      # the stream's end, after its last frame event
                    events.publish(self.id, {"event": "end", "id": self.id, "state": self.state,
                                             "frames": len(self.frames), "stop_reason": self.stop_reason,
                                             "error": self.error})
                self.done.set()
