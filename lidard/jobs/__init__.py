"""The scan worker: the one thread that owns the instrument, and the FIFO queue in front of it.

Rooms: :mod:`.worker` (the queue, the thread, submit/cancel/wait, calibration reuse),
:mod:`.scan_job` (one scan: run, adaptive passes, write, outcome), :mod:`.kinds` (job kinds, errors,
request records), :mod:`.events` (subscribers and live listeners), :mod:`.reprocess` (a stored scan's
raw capture through the DSP again, as a new linked scan: above both the store and lidard.raw, which
the instrument records through). Import from ``lidard.jobs``.

The FPSA, the AWG, the digitizer and the laser/HV controller form one optical path (§4.4, Fig. 4-33),
so only one job can use them at a time. Every job (a scan or a chirp linearization, §2.2) goes through
one FIFO queue served by one worker thread; nothing else calls the instrument's measuring methods.

Policy (also in docs/api.md):

* FIFO, one job at a time; at most ``max_queue`` jobs waiting (:class:`QueueFull` otherwise; the API
  answers 503).
* A scan uses the newest stored calibration of the configured laser; with none, or when the laser's
  TEC temperature is now more than ``recalibrate_delta_c`` (``scan.recalibrate_delta_c``) away from the
  calibration's, the worker runs ``instrument.linearize()`` first and stores the result. Otherwise the
  linearization health check (``instrument.check_linearization``) measures the stored drive's
  chirp and a chirp error above ``scan.linearity_threshold_hz`` re-linearizes first; the scan's sidecar
  records the check as ``linearization``.
* Before every scan and linearization the newest stored range and pointing calibrations
  (:mod:`.calibrations`) are handed to the instrument; a stored linearization made against
  another monitor delay than the range calibration's is stale and redone. Only records made on the
  instrument's own set-up are handed over (``setup``, lidard.instrument.calibration.setup); the scan
  says why others were not (``uncalibrated_reason``). Calibration measurements (plates, pointing
  targets, the guided procedure of :mod:`.guided`) are queued like any job (``submit_task``).
* A simulated bench with ``factory`` set (:class:`.guided.FactoryCalibration`) and no range/pointing
  record of its set-up runs its factory calibration before the first scan (stage ``calibrating``),
  once per worker.
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
  of :func:`lidard.instrument.plan.adaptive_plans`, whose points are fed back, then the dense pass; the points
  are merged (``t`` of the second pass offset by the first pass's hardware time). The instrument
  therefore never sees ``pattern="adaptive"``.
* Output: ``data_dir/scans/<id>/scan.<fmt>`` and ``scan.<fmt>.json`` per requested format.
"""

from __future__ import annotations

from .events import Event, EventHub, PointListener, Subscriber
from .kinds import (JobFailed, QueueFull, UnknownScan, WorkerStopped, describe_error, request_from_dict,
                    request_to_dict, software_version)
from .scan_job import ScanJobRun
from .worker import ScanWorker

__all__ = ["Event", "EventHub", "JobFailed", "PointListener", "QueueFull", "ScanJobRun", "ScanWorker", "Subscriber",
           "UnknownScan", "WorkerStopped", "describe_error", "request_from_dict", "request_to_dict",
           "software_version"]
