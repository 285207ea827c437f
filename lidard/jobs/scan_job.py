"""One scan job, from ``queued`` to a terminal state, on the worker thread (lidard.jobs).

:class:`ScanJobRun` is the explicit context of a running scan (what the worker used to keep in closures
and ``[value]`` cells): the calibration it uses, when the store last heard its progress, and the
steps run → (adaptive coarse + dense passes) → write the point clouds → record the outcome. The
outcomes and their states are the policy of :mod:`lidard.jobs` (cancelled, failed with the partial
points kept, stopped by the safety monitor, done).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from typing import Any, Protocol

from ..instrument.calibration.applied import AppliedCalibrations
from ..instrument.errors import ScanFailed
from ..instrument.protocol import Instrument
from ..instrument.types import CalibrationResult, ScanCancelled, ScanProgress, ScanRequest, ScanResult
from ..outputs import suffix_of, write_points
from ..physics.optics import FpsaOptics
from ..instrument.plan import adaptive_plans, planned_pixel_count
from ..store import Store
from .events import EventHub
from .kinds import _ScanJob, describe_error, request_to_dict, software_version


def raw_path(store, scan_id: str):
    """Where a scan's raw capture lives (zarr is loaded only when a scan records)."""
    from ..raw.capture import RAW_NAME
    return store.scan_dir(scan_id) / RAW_NAME

log = logging.getLogger("lidard.jobs")


class ScanHost(Protocol):
    """What a scan needs from the worker that runs it (:class:`lidard.jobs.worker.ScanWorker`): its
    store, instrument and event hub, the metadata and progress interval it was given, the geometry
    calibrations it applied, the calibration for a scan, whether it is stopping (a cancelled scan is
    then ``interrupted``) and the end of a scan (``finish_scan``: raw size, the end event, waiters)."""

    store: Store
    instrument: Instrument
    events: EventHub
    base_meta: dict[str, Any]
    progress_interval_s: float
    optics: FpsaOptics | None
    applied: AppliedCalibrations | None

    @property
    def stopping(self) -> bool: ...

    def calibration_for_scan(self, job: _ScanJob) -> CalibrationResult: ...

    def finish_scan(self, job: _ScanJob) -> None: ...


class ScanJobRun:
    """The context of one scan on the worker thread."""

    def __init__(self, worker: ScanHost, job: _ScanJob) -> None:
        self.w, self.job = worker, job
        self.store, self.instrument = worker.store, worker.instrument
        self.t0 = time.monotonic()
        self.last_store_s = float("-inf")   # the store hears progress at most every progress_interval_s
        self.cal_id: str | None = None

    # -- the steps ------------------------------------------------------------------------------
    def run(self) -> None:
        job = self.job
        started = time.time()
        self.t0 = time.monotonic()
        if not self.store.transition(job.id, ("queued",), state="running", stage="preparing",
                                     started=started):
            self.w.finish_scan(job)
            return
        try:
            result = self._measure()
        except ScanCancelled:
            self.store.update_scan(job.id, state="cancelled", stage="cancelled", partial=True,
                                   finished=time.time(), wall_time_s=time.monotonic() - self.t0)
            self.w.finish_scan(job)
            return
        except Exception as exc:
            self._failed(exc)
            return
        self._measured(result)

    def progress(self, p: ScanProgress) -> None:
        job = self.job
        ev = {"event": "progress", "id": job.id, "stage": p.stage, "pixels_done": p.pixels_done,
              "pixels_planned": p.pixels_planned, "points": p.points, "fraction": p.fraction,
              "hardware_time_s": p.hardware_time_s}
        now = time.monotonic()
        if now - self.last_store_s >= self.w.progress_interval_s or p.pixels_done >= p.pixels_planned:
            self.last_store_s = now
            self.store.update_scan(job.id, progress=p.fraction, stage=p.stage,
                                   pixels_scanned=p.pixels_done, pixels_planned=p.pixels_planned,
                                   points=p.points, hardware_time_s=p.hardware_time_s)
        batch = p.new_points                    # the points measured since the last call, or None
        if batch is not None and len(batch):
            self.w.events.points_out(job.id, batch, False)
        self.w.events.publish(job.id, ev)

    def _measure(self) -> ScanResult:
        job = self.job
        cal = self.w.calibration_for_scan(job)
        self.cal_id = cal.meta.get("id")
        applied = self.w.applied or AppliedCalibrations()
        iq = bool(getattr(self.instrument, "iq_receiver", False))
        self.store.update_scan(job.id, stage="scanning", calibration_id=self.cal_id,
                               range_calibration_id=applied.range_id, pointing_calibration_id=applied.pointing_id,
                               receiver="iq" if iq else "real", iq_calibration_id=applied.iq_id if iq else None,
                               uncalibrated_reason=applied.uncalibrated_reason)
        if job.request.pattern == "adaptive" and self.w.optics is not None:
            return run_adaptive(self.instrument, job, self.progress, cal, self.w.optics)
        # the raw capture goes next to the point clouds; only asked of the instrument when wanted
        raw = {"raw_path": raw_path(self.store, job.id)} if job.request.record_raw else {}
        return self.instrument.run_scan(job.request, self.progress, job.cancel, cal, **raw)

    # -- the outcomes ---------------------------------------------------------------------------
    def _failed(self, exc: Exception) -> None:
        job = self.job
        log.warning("scan %s failed: %s", job.id, describe_error(exc))
        partial_result = exc.partial if isinstance(exc, ScanFailed) else None
        files: dict[str, str] = {}
        counts: dict[str, Any] = {}
        if isinstance(partial_result, ScanResult) and partial_result.pixels_scanned > 0:
            # keep what was measured before the device went down
            try:
                files = self.write(dataclasses.replace(partial_result, partial=True), time.monotonic() - self.t0)
                self.w.events.points_out(job.id, partial_result.points, True)
                counts = dict(points=int(len(partial_result.points)),
                              pixels_scanned=int(partial_result.pixels_scanned),
                              pixels_planned=int(partial_result.pixels_planned),
                              hardware_time_s=float(partial_result.hardware_time_s))
            except Exception:
                log.exception("writing the partial points of failed scan %s failed", job.id)
                files, counts = {}, {}
        self.store.update_scan(job.id, state="failed", stage="failed", error=describe_error(exc),
                               finished=time.time(), wall_time_s=time.monotonic() - self.t0,
                               partial=bool(files), files=files, **counts)
        self.w.finish_scan(job)

    def _measured(self, result: ScanResult) -> None:
        job = self.job
        wall = time.monotonic() - self.t0
        try:
            files = self.write(result, wall)
        except Exception as exc:
            self.store.update_scan(job.id, state="failed", stage="failed", finished=time.time(),
                                   error=f"writing the point cloud failed: {describe_error(exc)}",
                                   wall_time_s=wall)
            self.w.finish_scan(job)
            return
        self.w.events.points_out(job.id, result.points, True)
        partial = bool(result.partial or job.cancel.is_set())
        stop_reason = getattr(result, "stop_reason", None)
        if stop_reason:
            state = "failed"
            log.warning("scan %s stopped: %s", job.id, stop_reason)
        elif job.cancel.is_set():
            state = "interrupted" if self.w.stopping else "cancelled"
            log.info("scan %s %s: %s", job.id, state, job.cancel_reason)
        else:
            state = "done"
        self.store.update_scan(
            job.id, state=state, stage=state, partial=partial, files=files, finished=time.time(),
            error=(f"SafetyStop: {stop_reason}" if stop_reason
                   else job.cancel_reason if state == "interrupted" else None),
            points=int(len(result.points)), pixels_scanned=int(result.pixels_scanned),
            pixels_planned=int(result.pixels_planned), hardware_time_s=float(result.hardware_time_s),
            wall_time_s=wall, progress=(result.pixels_scanned / result.pixels_planned
                                        if result.pixels_planned else 1.0))
        self.w.finish_scan(job)

    def write(self, result: ScanResult, wall_s: float) -> dict[str, str]:
        """Write every requested format under ``data_dir/scans/<id>/``; return {format: relative path}."""
        job = self.job
        meta = {
            **self.w.base_meta, **result.meta,
            "scan_id": job.id,
            "request": request_to_dict(job.request),
            "calibration_id": self.cal_id,
            "linearization": job.linearization,
            # which calibrations the points were computed with, said in every sidecar
            **self._calibrated(),
            "hardware_time_s": float(result.hardware_time_s),
            "wall_time_s": float(wall_s),
            "pixels_scanned": int(result.pixels_scanned),
            "pixels_planned": int(result.pixels_planned),
            "coverage": (result.pixels_scanned / result.pixels_planned) if result.pixels_planned else 0.0,
            "software_version": software_version(),
            "simulated": bool(self.instrument.simulated),
            "partial": bool(result.partial or job.cancel.is_set()),
            "stop_reason": result.stop_reason or (job.cancel_reason if job.cancel.is_set() else None),
        }
        out_dir = self.store.scan_dir(job.id)
        files: dict[str, str] = {}
        for fmt in job.request.formats:
            path = out_dir / f"scan{suffix_of(fmt)}"
            write_points(path, result.points, meta, fmt)
            files[fmt] = str(path.relative_to(self.store.data_dir))
        return files

    def _calibrated(self) -> dict[str, Any]:
        # what the scan was computed with (none handed over yet: the nominal geometry)
        applied = self.w.applied or AppliedCalibrations()
        return {"range_calibration_id": applied.range_id, "pointing_calibration_id": applied.pointing_id,
                "calibrated": applied.calibrated(self.cal_id is not None,
                                                 iq=bool(getattr(self.instrument, "iq_receiver", False))),
                "uncalibrated_reason": applied.uncalibrated_reason}


def run_adaptive(instrument, job: _ScanJob, progress: Callable[[ScanProgress], None],
                 cal: CalibrationResult, optics) -> ScanResult:
    """An adaptive scan as two ``pixels`` scans: the coarse pass, then the dense pass its points ask
    for (:func:`lidard.instrument.plan.adaptive_plans`), merged (the second pass's ``t`` offset by the first's
    hardware time). A failure of the dense pass carries the coarse points as its partial result."""
    import numpy as np
    req = job.request
    upper = planned_pixel_count(req, optics)
    gen = adaptive_plans(req, optics)
    coarse = next(gen)

    def as_pixels(px) -> ScanRequest:
        return dataclasses.replace(req, pattern="pixels", rows=None, cols=None,
                                   pixels=tuple((int(r), int(c)) for r, c in px))

    # the dense pass's size is unknown until the coarse points are in: report the ROI as the bound
    def coarse_progress(p: ScanProgress) -> None:
        progress(dataclasses.replace(p, pixels_planned=upper))

    first = instrument.run_scan(as_pixels(coarse), coarse_progress, job.cancel, cal)
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

    nothing = dataclasses.replace(first, points=first.points[:0], pixels_scanned=0, hardware_time_s=0.0, meta={})
    try:
        second = instrument.run_scan(as_pixels(dense), dense_progress, job.cancel, cal)
    except ScanFailed as exc:
        # the coarse pass is measured data: it rides on the failure like any partial result
        exc.partial = merged(exc.partial if exc.partial is not None else nothing)
        raise
    except ScanCancelled:
        raise
    except Exception as exc:
        # any other failure of the dense pass: a ScanFailed, so that the coarse points have a typed home
        raise ScanFailed(f"the dense pass of the adaptive scan failed: {exc}", partial=merged(nothing)) from exc
    return merged(second)
