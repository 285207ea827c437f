"""The scan worker: the one thread that owns the instrument, and the FIFO queue in front of it.

The queue, the worker thread, submitting, cancelling and waiting, and the calibration a scan uses;
one scan's run is :class:`lidard.jobs.scan_job.ScanJobRun`, the job kinds and errors are
:mod:`lidard.jobs.kinds`, subscribers and live listeners :mod:`lidard.jobs.events`. The policy is in
the :mod:`lidard.jobs` package docstring (and docs/api.md).
"""

from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import logging
import math
import threading
import time
from typing import Any
from collections.abc import Callable

from ..instrument.calibration.applied import AppliedCalibrations
from ..instrument.healthcheck import health_record
from ..instrument.protocol import Instrument
from ..instrument.types import CalibrationResult, ScanRequest
from ..physics.optics import FpsaOptics
from ..instrument.plan import planned_pixel_count
from ..store import ScanRecord, Store
from .. import heap
from .events import EventHub, PointListener, Subscriber
from .guided import FactoryCalibration
from .kinds import (QueueFull, UnknownScan, WorkerStopped, _CalibrationJob, _ScanJob, _SelftestJob, _TaskJob,
                    detached, request_to_dict)
from .scan_job import ScanJobRun, raw_path

log = logging.getLogger("lidard.jobs")


class ScanWorker:
    """Owns ``instrument``; runs queued jobs one at a time in a daemon thread."""

    def __init__(self, instrument: Instrument, store: Store, *, laser: str, max_queue: int = 16,
                 progress_interval_s: float = 0.25, meta: dict[str, Any] | None = None,
                 pixels_planned: Callable[[ScanRequest], int] | None = None,
                 optics: FpsaOptics | None = None, recalibrate_delta_c: float = 0.5, setup=None,
                 warm_dsp_pool: bool = True):
        """``warm_dsp_pool``: start the DSP's worker processes beside the queue (a daemon); a one-shot
        command whose scan the instrument was told of (Instrument.expect_scan) has started them already
        if its scan needs them."""
        self.instrument = instrument
        self.warm_dsp_pool = warm_dsp_pool
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
        self.last_linearization: dict[str, Any] | None = None   # the last scan's health check (GET /health)
        self._cv = threading.Condition()
        self._queue: collections.deque = collections.deque()
        self._jobs: dict[str, _ScanJob] = {}
        self._current: _ScanJob | _CalibrationJob | None = None
        self.events = EventHub()
        self._stopping = False
        self._thread: threading.Thread | None = None
        self.applied: AppliedCalibrations | None = None   # the AppliedCalibrations last handed to the instrument (apply_geometry)
        # the instrument's set-up (lidard.instrument.calibration.setup.CalibrationSetup): records are
        # made on it and only records made on it are applied; None (a test double): the newest record
        self.setup = setup
        # a simulated bench's factory calibration (lidard.jobs.guided.FactoryCalibration): run before the
        # first scan when no range/pointing record of this set-up is stored; None: never
        self.factory: FactoryCalibration | None = None
        self.sim_scene: dict[str, Any] | None = None   # the scene last placed over REST (PUT /sim/scene)

    # -- lifecycle -----------------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is not None:
            return
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="lidard-scan-worker", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float | None = 30.0, reason: str = "the daemon stopped") -> None:
        """Cancel the running scan (its points are kept; ``reason`` becomes its stop reason), mark
        queued ones interrupted, join."""
        with self._cv:
            self._stopping = True
            pending = list(self._queue)
            self._queue.clear()
            cur = self._current
            if isinstance(cur, _ScanJob) and not cur.cancel.is_set():
                cur.cancel_reason = reason
                cur.cancel.set()
            self._cv.notify_all()
        for job in pending:
            if isinstance(job, _ScanJob):
                self.store.transition(job.id, ("queued",), state="interrupted", stage="interrupted",
                                      error="daemon stopped before the scan started", finished=time.time())
                self.finish_scan(job)
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
    def _check_room(self) -> None:
        # called with self._cv held
        if self._stopping:
            raise WorkerStopped("the scan worker is stopping; no new jobs are accepted")
        if len(self._queue) >= self.max_queue:
            raise QueueFull(f"scan queue is full ({self.max_queue} jobs waiting); retry when one finishes")

    def _enqueue(self, job) -> None:
        # called with self._cv held
        self._check_room()
        self._queue.append(job)
        self._cv.notify_all()

    def submit_scan(self, request: ScanRequest) -> ScanRecord:
        planned = self._pixels_planned(request) if self._pixels_planned else 0
        with self._cv:
            self._check_room()              # before the store records a scan that could not queue
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

    def submit_task(self, fn: Callable[[], Any]) -> concurrent.futures.Future:
        """Queue ``fn()`` (a procedure that drives the instrument, e.g. a calibration measurement) behind
        the jobs already waiting; the future resolves to its result or its exception."""
        job = _TaskJob(fn)
        with self._cv:
            self._enqueue(job)
        return job.future

    def cancel(self, scan_id: str, reason: str = "cancelled") -> ScanRecord:
        """Cancel a queued or running scan (``reason``: the sidecar's stop reason of its partial
        points); a finished one is returned unchanged."""
        with self._cv:
            job = self._jobs.get(scan_id)
            if job is not None and job in self._queue:
                self._queue.remove(job)
                self.store.transition(scan_id, ("queued",), state="cancelled", stage="cancelled",
                                      finished=time.time())
                self.finish_scan(job)
            elif job is not None and not job.cancel.is_set():
                job.cancel_reason = reason
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

    # -- subscribers (lidard.jobs.events) -------------------------------------------------------
    def subscribe(self, scan_id: str, fn: Subscriber) -> Callable[[], None]:
        """Call ``fn(event)`` for each progress event of one scan and its end; returns the unsubscriber."""
        return self.events.subscribe(scan_id, fn)

    def add_point_listener(self, fn: PointListener) -> None:
        """Call ``fn(scan_id, points, final)`` for every batch of points a scan hands over (when the
        instrument's progress carries ``new_points``) and once with the whole cloud when it is written."""
        self.events.add_point_listener(fn)

    def add_event_listener(self, fn: Subscriber) -> None:
        """Call ``fn(event)`` for the progress and end events of every scan (live publishers)."""
        self.events.add_event_listener(fn)

    @property
    def stopping(self) -> bool:
        """True once :meth:`stop` was called (a scan cancelled then is ``interrupted``, not ``cancelled``)."""
        return self._stopping

    def finish_scan(self, job: _ScanJob) -> None:
        """A scan reached its terminal state: record its raw capture's size, publish its end event,
        wake its waiters."""
        if job.request.record_raw:   # whatever the outcome: a capture (maybe a partial prefix) is on disk
            from ..raw.capture import capture_size_bytes
            size = capture_size_bytes(raw_path(self.store, job.id))
            self.store.update_scan(job.id, raw_bytes=size or None)
        rec = self.store.get_scan(job.id)
        self.events.publish(job.id, {"event": "end", "id": job.id, "state": rec.state if rec else "unknown",
                               "partial": bool(rec.partial) if rec else False,
                               "error": rec.error if rec else None})
        job.done.set()
        self._jobs.pop(job.id, None)

    # -- the worker ----------------------------------------------------------------------------
    def _run(self) -> None:
        if self.setup is not None and self.warm_dsp_pool:   # a real instrument (not a test double): its first scan finds the
            # DSP worker processes started. Beside the queue, not before it: a scan queued at start-up
            # runs at once (it waits for the pool only if it needs it before the pool is up). Imported
            # here so that the API and the queue load no DSP (tests/lidard/test_instrument_rooms.py).
            from ..dsp_pool import warm_in_background
            warm_in_background()
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
                    ScanJobRun(self, job).run()
                elif isinstance(job, _SelftestJob):
                    self._run_selftest(job)
                elif isinstance(job, _TaskJob):
                    self._run_task(job)
                else:
                    self._run_calibration(job)
            except Exception:  # never let the worker thread die
                log.exception("scan worker job failed unexpectedly")
            finally:
                with self._cv:
                    self._current = None
                heap.trim()     # a daemon's RSS must not creep up job after job (lidard.heap)

    def _run_calibration(self, job: _CalibrationJob) -> None:
        if not job.future.set_running_or_notify_cancel():
            return
        try:
            self.apply_geometry()   # the ILC targets the range-calibrated monitor delay
            cal = self._own_laser(self.instrument.linearize())
            cal.meta = {**cal.meta, "id": self.store.save_calibration(cal)}
            job.future.set_result(cal)
        except Exception as exc:
            job.future.set_exception(detached(exc))

    def _run_task(self, job: _TaskJob) -> None:
        if not job.future.set_running_or_notify_cancel():
            return
        try:
            job.future.set_result(job.fn())
        except Exception as exc:
            job.future.set_exception(detached(exc))

    def _run_selftest(self, job: _SelftestJob) -> None:
        if not job.future.set_running_or_notify_cancel():
            return
        try:
            report = self.instrument.selftest()
            log.info("self-test: %s", "all switches respond" if report.get("ok") else
                     f"stuck switches: {report.get('stuck')}")
            job.future.set_result(report)
        except Exception as exc:
            job.future.set_exception(detached(exc))

    def _stale_reason(self, cal: CalibrationResult) -> str | None:
        """Why a stored calibration must not be reused (the laser's temperature moved, or it targets
        another monitor delay than the range calibration's), or None."""
        used = cal.meta.get("mzi_delay_s")
        want = self.instrument.monitor_delay_s()
        if used is not None and abs(float(used) - want) > 1e-9 * want:
            return (f"calibration {cal.meta.get('id')} was linearized against a {float(used) * 1e9:.4f} ns monitor "
                    f"delay; the range calibration says {want * 1e9:.4f} ns")
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

    def calibration_for_scan(self, job: _ScanJob) -> CalibrationResult:
        """The newest stored calibration of the laser, or a new linearization when there is none, when
        the laser's temperature moved, when the range calibration changed the monitor delay it targets,
        or when the linearization health check finds its chirp off (announced as the scan's
        ``linearizing`` stage). ``job.linearization`` records the check."""
        def announce(step: dict | None = None) -> None:
            # first the stage, then each of the linearization's measurements (its progress)
            if step is None:
                self.store.update_scan(job.id, stage="linearizing")
            self.events.publish(job.id, {"event": "progress", "id": job.id, "stage": "linearizing",
                                   "pixels_done": 0, "pixels_planned": 0, "points": 0,
                                   "fraction": 0.0, "hardware_time_s": 0.0, **(step or {})})
        if self.factory is not None and not self.factory.tried:
            self._factory_calibration(job)
        cal = self.current_linearization(announce, request=job.request)
        job.linearization = self.last_linearization
        return cal

    def _factory_calibration(self, job: _ScanJob) -> None:
        """The bench's factory calibration before this scan, announced as its ``calibrating`` stage."""
        def stage(ev: dict[str, Any]) -> None:
            done, steps = ev.get("done"), ev.get("steps")
            self.events.publish(job.id, {"event": "progress", "id": job.id, "stage": "calibrating",
                                         "pixels_done": 0, "pixels_planned": 0, "points": 0,
                                         "fraction": (done / steps) if done is not None and steps else 0.0,
                                         "hardware_time_s": 0.0, "calibration": ev})
        self.store.update_scan(job.id, stage="calibrating")
        if self.factory is not None:
            self.factory.run_if_needed(self, stage)

    def phase_noise_of(self, request) -> str | None:
        """The phase-noise compensation a scan of ``request`` runs with ("on"/"off"; None for an
        instrument without a configuration, a test double): the range record it uses must share it."""
        from ..instrument.calibration.procedures import scan_phase_noise
        cfg = getattr(self.instrument, "cfg", None)
        if cfg is None:
            return None
        delay = getattr(self.instrument, "monitor_delay_s", None)
        return scan_phase_noise(cfg, request, delay() if callable(delay) else cfg.monitor.delay_s)

    def current_linearization(self, announce: Callable[..., None] | None = None,
                              request=None) -> CalibrationResult:
        """On the worker thread: apply the stored range/pointing calibrations, then the newest stored
        linearization if it is fresh (temperature rule, monitor delay) and passes the health check,
        else a new one (``announce()`` first). ``self.last_linearization`` records the check.
        ``request``: the scan (or stream) this is for; a range record must have been measured in its
        phase-noise compensation mode (None: a record of either mode, e.g. for a calibration's own scans)."""
        self.apply_geometry(None if request is None else self.phase_noise_of(request))
        cal = self.store.latest_calibration(self.laser)
        reason = "no calibration stored" if cal is None else self._stale_reason(cal)
        checked = self.instrument.check_linearization(cal) if reason is None else None
        if checked is not None and checked.exceeded:
            reason = checked.reason()
        used = checked
        if reason is not None:
            log.info("linearizing: %s", reason)
            if announce is not None:
                announce()
            cal = self._own_laser(self.instrument.linearize(announce))
            cal.meta = {**cal.meta, "id": self.store.save_calibration(cal)}
            used = self.instrument.check_linearization(cal)
        self.last_linearization = health_record(checked, used, reason)
        assert cal is not None   # with none stored, reason was set and one was made
        return cal

    def apply_geometry(self, phase_noise: str | None = None):
        """Hand the newest stored range, pointing and I/Q calibrations made on this instrument's set-up
        to the instrument; answers the :class:`AppliedCalibrations`, whose ``notes`` say
        why records of another set-up were left unused. Runs on the worker thread before every scan and
        linearization. ``phase_noise`` ("on"/"off"): the scan's phase-noise compensation; a range record
        measured in the other mode is left unused (None: any mode)."""
        from ..instrument.calibration.setup import select
        chosen, notes = {}, []
        for kind in ("range", "pointing", "iq"):
            rec, why = select(self.store.geometry.recent(kind, limit=200),
                              None if self.setup is None else self.setup[kind], phase_noise)
            chosen[kind] = rec
            if why is not None:
                notes.append(why)
        if self.factory is not None and self.factory.refused:
            notes.append(f"the factory calibration was refused: {self.factory.refused}")
        self.applied = AppliedCalibrations.from_records(chosen["range"], chosen["pointing"], chosen["iq"],
                                                        notes=tuple(notes))
        self.instrument.use_calibrations(self.applied)
        return self.applied

    def setup_of(self, kind: str) -> dict[str, Any] | None:
        """What a new record of ``kind`` names as its set-up (None when the set-up is not known)."""
        return None if self.setup is None else self.setup[kind].as_dict()

    def _own_laser(self, cal: CalibrationResult) -> CalibrationResult:
        # Cache under the configured laser name, whatever the instrument calls it, so that the next
        # scan finds it (latest_calibration looks up by the configured name).
        if cal.laser != self.laser:
            cal = dataclasses.replace(cal, laser=self.laser, meta={**cal.meta, "reported_laser": cal.laser})
        return cal
