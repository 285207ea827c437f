"""The scan worker: the one thread that owns the instrument, and the FIFO queue in front of it.

The FPSA, the AWG, the digitizer and the laser/HV controller form one optical path (§4.4, Fig. 4-33),
so only one job can use them at a time. Every job (a scan or a chirp linearization, §2.2) goes through
one FIFO queue served by one worker thread; nothing else calls the instrument's measuring methods.

Policy (also in docs/api.md):

* FIFO, one job at a time; at most ``max_queue`` jobs waiting (:class:`QueueFull` otherwise; the API
  answers 503).
* A scan uses the newest stored calibration of the configured laser; with none, or when the laser's
  TEC temperature is now more than ``recalibrate_delta_c`` (``scan.recalibrate_delta_c``) away from the
  calibration's, the worker runs ``instrument.linearize()`` first and stores the result.
* Cancel: a queued scan becomes ``cancelled`` at once; a running scan's cancel event is set, the
  instrument returns the points so far, which are written and marked ``partial``.
* Failure: the state becomes ``failed`` and ``error`` holds the exception type, message and cause
  (which names the device). When the instrument hands back the points measured before the failure
  (``ScanFailed.partial``), they are written like any partial scan: nothing measured is lost.
* Safety stop (interlock opened, HV fault mid-scan): the instrument returns ``stop_reason``; the scan
  is written with ``partial`` and ends ``failed`` with that reason as its ``error``.
* Self-test (``submit_selftest``) is queued like a linearization and resolves to the report.
* Progress updates the store at most every ``progress_interval_s`` (wall clock; it only throttles
  database writes) and is published to subscribers (the SSE endpoint, the CLI's progress bar). The
  last event of a scan is ``{"event": "end", ...}``.
* Adaptive scans (when the worker knows the optics) run as two ``pixels`` requests: the coarse pass
  of :func:`lidard.scan.adaptive_plans`, whose points are fed back, then the dense pass; the points
  are merged (``t`` of the second pass offset by the first pass's hardware time). The instrument
  therefore never sees ``pattern="adaptive"``.
* Output: ``data_dir/scans/<id>/scan.<fmt>`` and ``scan.<fmt>.json`` per requested format.
"""

from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import logging
import math
import threading
import time
from importlib import metadata
from typing import Any, Callable

from .errors import LidardError
from .instrument.protocol import Instrument
from .instrument.types import CalibrationResult, ScanCancelled, ScanProgress, ScanRequest, ScanResult
from .physics.optics import FpsaOptics
from .pointcloud import write_points
from .scan import adaptive_plans, planned_pixel_count
from .store import ScanRecord, Store

log = logging.getLogger(__name__)

Event = dict[str, Any]
Subscriber = Callable[[Event], None]
# (scan_id, POINT_DTYPE records, final): a batch measured so far, or (final=True) the whole cloud
PointListener = Callable[[str, Any, bool], None]


class QueueFull(LidardError):
    """The job queue is at its limit; try again after the running jobs finish."""


class UnknownScan(LidardError):
    """No scan with that id."""


class WorkerStopped(LidardError):
    """The worker is not running (daemon shutting down)."""


def software_version() -> str:
    try:
        return metadata.version("lidard")
    except metadata.PackageNotFoundError:
        return "0+unknown"


def describe_error(exc: BaseException) -> str:
    """One line: type, message and the chain of causes (the device error is usually the cause)."""
    parts = [f"{type(exc).__name__}: {exc}"]
    seen = {id(exc)}
    cur = exc.__cause__ or exc.__context__
    while cur is not None and id(cur) not in seen:
        seen.add(id(cur))
        parts.append(f"caused by {type(cur).__name__}: {cur}")
        cur = cur.__cause__ or cur.__context__
    return "; ".join(parts)


def request_to_dict(req: ScanRequest) -> dict[str, Any]:
    d = dataclasses.asdict(req)
    for k in ("rows", "cols"):
        d[k] = None if d[k] is None else list(d[k])
    d["pixels"] = None if d["pixels"] is None else [list(p) for p in d["pixels"]]
    d["formats"] = list(d["formats"])
    return d


def request_from_dict(d: dict[str, Any]) -> ScanRequest:
    return ScanRequest(
        pattern=d.get("pattern", "raster"),
        rows=None if d.get("rows") is None else tuple(d["rows"]),
        cols=None if d.get("cols") is None else tuple(d["cols"]),
        pixels=None if d.get("pixels") is None else tuple(tuple(p) for p in d["pixels"]),
        averages=int(d.get("averages", 1)), max_range_m=float(d.get("max_range_m", 2.0)),
        formats=tuple(d.get("formats", ("ply",))),
        phase_noise_compensation=d.get("phase_noise_compensation"))


@dataclasses.dataclass
class _ScanJob:
    id: str
    request: ScanRequest
    cancel: threading.Event = dataclasses.field(default_factory=threading.Event)
    done: threading.Event = dataclasses.field(default_factory=threading.Event)


@dataclasses.dataclass
class _CalibrationJob:
    future: concurrent.futures.Future = dataclasses.field(default_factory=concurrent.futures.Future)


@dataclasses.dataclass
class _SelftestJob:
    future: concurrent.futures.Future = dataclasses.field(default_factory=concurrent.futures.Future)


class ScanWorker:
    """Owns ``instrument``; runs queued jobs one at a time in a daemon thread."""

    def __init__(self, instrument: Instrument, store: Store, *, laser: str, max_queue: int = 16,
                 progress_interval_s: float = 0.25, meta: dict[str, Any] | None = None,
                 pixels_planned: Callable[[ScanRequest], int] | None = None,
                 optics: FpsaOptics | None = None, recalibrate_delta_c: float = 0.5):
        self.instrument = instrument
        self.store = store
        self.laser = laser
        self.max_queue = max_queue
        self.progress_interval_s = progress_interval_s
        self.base_meta = dict(meta or {})
        self._pixels_planned = pixels_planned
        if pixels_planned is None and optics is not None:
            self._pixels_planned = lambda req: planned_pixel_count(req, optics)
        self.optics = optics
        self.recalibrate_delta_c = float(recalibrate_delta_c)
        self._cv = threading.Condition()
        self._queue: collections.deque = collections.deque()
        self._jobs: dict[str, _ScanJob] = {}
        self._current: _ScanJob | _CalibrationJob | None = None
        self._subs: dict[str, list[Subscriber]] = collections.defaultdict(list)
        self._subs_lock = threading.Lock()
        self._point_listeners: list[PointListener] = []
        self._event_listeners: list[Subscriber] = []
        self._stopping = False
        self._thread: threading.Thread | None = None

    # -- lifecycle -----------------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is not None:
            return
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="lidard-scan-worker", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float | None = 30.0) -> None:
        """Cancel the running scan (its points are kept), mark queued ones interrupted, join."""
        with self._cv:
            self._stopping = True
            pending = list(self._queue)
            self._queue.clear()
            cur = self._current
            if isinstance(cur, _ScanJob):
                cur.cancel.set()
            self._cv.notify_all()
        for job in pending:
            if isinstance(job, _ScanJob):
                self.store.transition(job.id, ("queued",), state="interrupted", stage="interrupted",
                                      error="daemon stopped before the scan started", finished=time.time())
                self._finish(job)
            else:
                job.future.set_exception(WorkerStopped("daemon stopped before the calibration ran"))
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def queue_length(self) -> int:
        with self._cv:
            return len(self._queue)

    def current_scan_id(self) -> str | None:
        cur = self._current
        return cur.id if isinstance(cur, _ScanJob) else None

    # -- submitting ----------------------------------------------------------------------------
    def _enqueue(self, job) -> None:
        # called with self._cv held
        if self._stopping:
            raise WorkerStopped("the scan worker is stopping; no new jobs are accepted")
        if len(self._queue) >= self.max_queue:
            raise QueueFull(f"scan queue is full ({self.max_queue} jobs waiting); retry when one finishes")
        self._queue.append(job)
        self._cv.notify_all()

    def submit_scan(self, request: ScanRequest) -> ScanRecord:
        planned = self._pixels_planned(request) if self._pixels_planned else 0
        with self._cv:
            if self._stopping:
                raise WorkerStopped("the scan worker is stopping; no new jobs are accepted")
            if len(self._queue) >= self.max_queue:
                raise QueueFull(f"scan queue is full ({self.max_queue} jobs waiting); "
                                "retry when one finishes")
            rec = self.store.create_scan(request_to_dict(request), pixels_planned=planned)
            job = _ScanJob(rec.id, request)
            self._jobs[rec.id] = job
            self._enqueue(job)
        return rec

    def submit_calibration(self) -> concurrent.futures.Future:
        job = _CalibrationJob()
        with self._cv:
            self._enqueue(job)
        return job.future

    def submit_selftest(self) -> concurrent.futures.Future:
        """Queue a switch self-test (``instrument.selftest()``); the future resolves to its report."""
        job = _SelftestJob()
        with self._cv:
            self._enqueue(job)
        return job.future

    def cancel(self, scan_id: str) -> ScanRecord:
        """Cancel a queued or running scan; a finished one is returned unchanged."""
        with self._cv:
            job = self._jobs.get(scan_id)
            if job is not None and job in self._queue:
                self._queue.remove(job)
                self.store.transition(scan_id, ("queued",), state="cancelled", stage="cancelled",
                                      finished=time.time())
                self._finish(job)
            elif job is not None:
                job.cancel.set()
        rec = self.store.get_scan(scan_id)
        if rec is None:
            raise UnknownScan(f"scan {scan_id!r} not found")
        return rec

    def wait(self, scan_id: str, timeout_s: float | None = None) -> ScanRecord:
        """Block until the scan reaches a terminal state (or the timeout) and return its record."""
        job = self._jobs.get(scan_id)
        if job is not None:
            job.done.wait(timeout_s)
        rec = self.store.get_scan(scan_id)
        if rec is None:
            raise UnknownScan(f"scan {scan_id!r} not found")
        return rec

    # -- subscribers ---------------------------------------------------------------------------
    def subscribe(self, scan_id: str, fn: Subscriber) -> Callable[[], None]:
        with self._subs_lock:
            self._subs[scan_id].append(fn)

        def unsubscribe() -> None:
            with self._subs_lock:
                lst = self._subs.get(scan_id, [])
                if fn in lst:
                    lst.remove(fn)
                if not lst:
                    self._subs.pop(scan_id, None)
        return unsubscribe

    def add_point_listener(self, fn: PointListener) -> None:
        """Call ``fn(scan_id, points, final)`` for every batch of points a scan hands over (when the
        instrument's progress carries ``new_points``) and once with the whole cloud when it is written."""
        self._point_listeners.append(fn)

    def add_event_listener(self, fn: Subscriber) -> None:
        """Call ``fn(event)`` for the progress and end events of every scan (live publishers)."""
        self._event_listeners.append(fn)

    def _points_out(self, scan_id: str, points, final: bool) -> None:
        for fn in list(self._point_listeners):
            try:
                fn(scan_id, points, final)
            except Exception:  # a broken viewer must not stop the scan
                log.exception("point listener for scan %s failed", scan_id)

    def _publish(self, scan_id: str, event: Event) -> None:
        with self._subs_lock:
            subs = list(self._subs.get(scan_id, ())) + self._event_listeners
        for fn in subs:
            try:
                fn(event)
            except Exception:  # a broken subscriber must not stop the scan
                log.exception("progress subscriber for scan %s failed", scan_id)

    def _finish(self, job: _ScanJob) -> None:
        rec = self.store.get_scan(job.id)
        self._publish(job.id, {"event": "end", "id": job.id, "state": rec.state if rec else "unknown",
                               "partial": bool(rec.partial) if rec else False,
                               "error": rec.error if rec else None})
        job.done.set()
        self._jobs.pop(job.id, None)

    # -- the worker ----------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._queue and not self._stopping:
                    self._cv.wait()
                if self._stopping and not self._queue:
                    return
                job = self._queue.popleft()
                self._current = job
            try:
                if isinstance(job, _ScanJob):
                    self._run_scan(job)
                elif isinstance(job, _SelftestJob):
                    self._run_selftest(job)
                else:
                    self._run_calibration(job)
            except Exception:  # never let the worker thread die
                log.exception("scan worker job failed unexpectedly")
            finally:
                with self._cv:
                    self._current = None

    def _run_calibration(self, job: _CalibrationJob) -> None:
        if not job.future.set_running_or_notify_cancel():
            return
        try:
            cal = self._own_laser(self.instrument.linearize())
            cal.meta = {**cal.meta, "id": self.store.save_calibration(cal)}
            job.future.set_result(cal)
        except Exception as exc:
            job.future.set_exception(exc)

    def _run_selftest(self, job: _SelftestJob) -> None:
        if not job.future.set_running_or_notify_cancel():
            return
        try:
            report = self.instrument.selftest()
            log.info("self-test: %s", "all switches respond" if report.get("ok") else
                     f"stuck switches: {report.get('stuck')}")
            job.future.set_result(report)
        except Exception as exc:
            job.future.set_exception(exc)

    def _stale_reason(self, cal: CalibrationResult) -> str | None:
        """Why a stored calibration must not be reused (the laser's temperature moved), or None."""
        try:
            now_c = float(self.instrument.laser_temperature_c())
        except Exception as exc:
            log.warning("laser temperature unreadable (%s); reusing calibration %s", exc, cal.meta.get("id"))
            return None
        then_c = float(cal.temperature_c)
        if not (math.isfinite(now_c) and math.isfinite(then_c)):
            return None
        if abs(now_c - then_c) > self.recalibrate_delta_c:
            return (f"laser at {now_c:.2f} C, calibration {cal.meta.get('id')} made at {then_c:.2f} C "
                    f"(more than {self.recalibrate_delta_c:g} C apart)")
        return None

    def _calibration(self, job: _ScanJob) -> CalibrationResult:
        cal = self.store.latest_calibration(self.laser)
        stale = None if cal is None else self._stale_reason(cal)
        if stale is not None:
            log.info("re-linearizing: %s", stale)
        if cal is None or stale is not None:
            self.store.update_scan(job.id, stage="linearizing")
            self._publish(job.id, {"event": "progress", "id": job.id, "stage": "linearizing",
                                   "pixels_done": 0, "pixels_planned": 0, "points": 0,
                                   "fraction": 0.0, "hardware_time_s": 0.0})
            cal = self._own_laser(self.instrument.linearize())
            cal.meta = {**cal.meta, "id": self.store.save_calibration(cal)}
        return cal

    def _own_laser(self, cal: CalibrationResult) -> CalibrationResult:
        # Cache under the configured laser name, whatever the instrument calls it, so that the next
        # scan finds it (latest_calibration looks up by the configured name).
        if cal.laser != self.laser:
            cal = dataclasses.replace(cal, laser=self.laser, meta={**cal.meta, "reported_laser": cal.laser})
        return cal

    def _run_scan(self, job: _ScanJob) -> None:
        started = time.time()
        t0 = time.monotonic()
        if not self.store.transition(job.id, ("queued",), state="running", stage="preparing",
                                     started=started):
            self._finish(job)
            return
        last_store = [float("-inf")]

        def progress(p: ScanProgress) -> None:
            ev = {"event": "progress", "id": job.id, "stage": p.stage, "pixels_done": p.pixels_done,
                  "pixels_planned": p.pixels_planned, "points": p.points, "fraction": p.fraction,
                  "hardware_time_s": p.hardware_time_s}
            now = time.monotonic()
            if now - last_store[0] >= self.progress_interval_s or p.pixels_done >= p.pixels_planned:
                last_store[0] = now
                self.store.update_scan(job.id, progress=p.fraction, stage=p.stage,
                                       pixels_scanned=p.pixels_done, pixels_planned=p.pixels_planned,
                                       points=p.points, hardware_time_s=p.hardware_time_s)
            batch = p.new_points                    # the points measured since the last call, or None
            if batch is not None and len(batch):
                self._points_out(job.id, batch, False)
            self._publish(job.id, ev)

        cal_id = None
        try:
            cal = self._calibration(job)
            cal_id = cal.meta.get("id")
            self.store.update_scan(job.id, stage="scanning", calibration_id=cal_id)
            if job.request.pattern == "adaptive" and self.optics is not None:
                result = self._run_adaptive(job, progress, cal)
            else:
                result = self.instrument.run_scan(job.request, progress, job.cancel, cal)
        except ScanCancelled:
            self.store.update_scan(job.id, state="cancelled", stage="cancelled", partial=True,
                                   finished=time.time(), wall_time_s=time.monotonic() - t0)
            self._finish(job)
            return
        except Exception as exc:
            log.warning("scan %s failed: %s", job.id, describe_error(exc))
            partial_result = getattr(exc, "partial", None)
            files: dict[str, str] = {}
            counts: dict[str, Any] = {}
            if isinstance(partial_result, ScanResult) and partial_result.pixels_scanned > 0:
                # keep what was measured before the device went down
                try:
                    files = self._write(job, dataclasses.replace(partial_result, partial=True), cal_id,
                                        time.monotonic() - t0)
                    self._points_out(job.id, partial_result.points, True)
                    counts = dict(points=int(len(partial_result.points)),
                                  pixels_scanned=int(partial_result.pixels_scanned),
                                  pixels_planned=int(partial_result.pixels_planned),
                                  hardware_time_s=float(partial_result.hardware_time_s))
                except Exception:
                    log.exception("writing the partial points of failed scan %s failed", job.id)
                    files, counts = {}, {}
            self.store.update_scan(job.id, state="failed", stage="failed", error=describe_error(exc),
                                   finished=time.time(), wall_time_s=time.monotonic() - t0,
                                   partial=bool(files), files=files, **counts)
            self._finish(job)
            return
        wall = time.monotonic() - t0
        try:
            files = self._write(job, result, cal_id, wall)
        except Exception as exc:
            self.store.update_scan(job.id, state="failed", stage="failed", finished=time.time(),
                                   error=f"writing the point cloud failed: {describe_error(exc)}",
                                   wall_time_s=wall)
            self._finish(job)
            return
        self._points_out(job.id, result.points, True)
        partial = bool(result.partial or job.cancel.is_set())
        stop_reason = getattr(result, "stop_reason", None)
        if stop_reason:
            state = "failed"
            log.warning("scan %s stopped: %s", job.id, stop_reason)
        elif job.cancel.is_set():
            state = "interrupted" if self._stopping else "cancelled"
        else:
            state = "done"
        self.store.update_scan(
            job.id, state=state, stage=state, partial=partial, files=files, finished=time.time(),
            error=(f"SafetyStop: {stop_reason}" if stop_reason else None),
            points=int(len(result.points)), pixels_scanned=int(result.pixels_scanned),
            pixels_planned=int(result.pixels_planned), hardware_time_s=float(result.hardware_time_s),
            wall_time_s=wall, progress=(result.pixels_scanned / result.pixels_planned
                                        if result.pixels_planned else 1.0))
        self._finish(job)

    def _run_adaptive(self, job: _ScanJob, progress, cal: CalibrationResult) -> ScanResult:
        import numpy as np
        req = job.request
        upper = planned_pixel_count(req, self.optics)
        gen = adaptive_plans(req, self.optics)
        coarse = next(gen)

        def as_pixels(px) -> ScanRequest:
            return dataclasses.replace(req, pattern="pixels", rows=None, cols=None,
                                       pixels=tuple((int(r), int(c)) for r, c in px))

        # the dense pass's size is unknown until the coarse points are in: report the ROI as the bound
        def coarse_progress(p: ScanProgress) -> None:
            progress(dataclasses.replace(p, pixels_planned=upper))

        first = self.instrument.run_scan(as_pixels(coarse), coarse_progress, job.cancel, cal)
        dense = gen.send(first.points)
        planned = len(coarse) + len(dense)
        if job.cancel.is_set() or first.partial or len(dense) == 0:
            return dataclasses.replace(first, pixels_planned=planned,
                                       partial=first.partial or job.cancel.is_set(),
                                       meta={**first.meta, "adaptive": {"coarse": len(coarse), "dense": len(dense)}})
        offset_s = first.hardware_time_s

        def dense_progress(p: ScanProgress) -> None:
            progress(ScanProgress(first.pixels_scanned + p.pixels_done, planned,
                                  len(first.points) + p.points, offset_s + p.hardware_time_s, p.stage))

        def merged(second: ScanResult) -> ScanResult:
            pts2 = second.points.copy()
            pts2["t"] += offset_s
            return ScanResult(points=np.concatenate([first.points, pts2]),
                              meta={**first.meta, **second.meta,
                                    "adaptive": {"coarse": len(coarse), "dense": len(dense)}},
                              pixels_scanned=first.pixels_scanned + second.pixels_scanned,
                              pixels_planned=planned, hardware_time_s=offset_s + second.hardware_time_s,
                              partial=second.partial, stop_reason=second.stop_reason)

        try:
            second = self.instrument.run_scan(as_pixels(dense), dense_progress, job.cancel, cal)
        except Exception as exc:
            # the coarse pass is measured data: it rides on the failure like any partial result
            part = getattr(exc, "partial", None)
            exc.partial = merged(part if isinstance(part, ScanResult) else dataclasses.replace(
                first, points=first.points[:0], pixels_scanned=0, hardware_time_s=0.0, meta={}))
            raise
        return merged(second)

    def _write(self, job: _ScanJob, result: ScanResult, cal_id: str | None, wall_s: float) -> dict[str, str]:
        meta = {
            **self.base_meta, **result.meta,
            "scan_id": job.id,
            "request": request_to_dict(job.request),
            "calibration_id": cal_id,
            "hardware_time_s": float(result.hardware_time_s),
            "wall_time_s": float(wall_s),
            "pixels_scanned": int(result.pixels_scanned),
            "pixels_planned": int(result.pixels_planned),
            "coverage": (result.pixels_scanned / result.pixels_planned) if result.pixels_planned else 0.0,
            "software_version": software_version(),
            "simulated": bool(self.instrument.simulated),
            "partial": bool(result.partial or job.cancel.is_set()),
            "stop_reason": result.stop_reason,
        }
        out_dir = self.store.scan_dir(job.id)
        files = {}
        for fmt in job.request.formats:
            path = out_dir / f"scan.{fmt}"
            write_points(path, result.points, meta, fmt)
            files[fmt] = str(path.relative_to(self.store.data_dir))
        return files
