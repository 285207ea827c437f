"""The job kinds of the scan worker's queue and what a job's record holds (lidard.jobs).

A scan (:class:`_ScanJob`, recorded in the store under its id), a chirp linearization (§2.2) and a
switch self-test (both resolved through a future); the errors the queue raises; and the one-line
description of a failure (type, message, causes) the store and the API show.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import threading
from importlib import metadata
from typing import Any

from ..errors import LidardError, UnknownScan  # noqa: F401  (UnknownScan re-exported)
from ..instrument.types import ScanRequest


class QueueFull(LidardError):
    """The job queue is at its limit; try again after the running jobs finish."""

    retry_after_s = 5


class JobFailed(LidardError):
    """A queued job (a linearization, a self-test, a calibration) failed on the worker; the message
    names the job and the chain of causes (503: the daemon's state, not the request's fault)."""


class WorkerStopped(LidardError):
    """The worker is not running (daemon shutting down)."""

    retry_after_s = 5


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


def detached(exc: BaseException) -> BaseException:
    """``exc`` and the exceptions it was raised from, without their tracebacks: for an exception kept
    past its handler (a job's future). A kept traceback keeps every frame it passed through, with their
    arrays (a failed linearization's MZI records: megabytes), and the handler's frame holds the job that
    holds the future that holds the exception: a cycle that only the cyclic collector frees, minutes
    apart in a daemon. What the caller reads of a failure (type, message, causes) stays.

    The drivers have the same rule for their parsers' kept errors (``drivers.errors.detached``); it is
    written twice on purpose: the drivers may not import the daemon, and the job queue loads no
    drivers (tests/lidard/test_instrument_rooms.py)."""
    seen: set[int] = set()
    todo: list[BaseException | None] = [exc]
    while todo:
        cur = todo.pop()
        if cur is None or id(cur) in seen:
            continue
        seen.add(id(cur))
        cur.__traceback__ = None
        todo += [cur.__cause__, cur.__context__]
    return exc


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
        max_speed_mps=None if d.get("max_speed_mps") is None else float(d["max_speed_mps"]),
        formats=tuple(d.get("formats", ("ply",))),
        phase_noise_compensation=d.get("phase_noise_compensation"),
        record_raw=bool(d.get("record_raw", False)))


@dataclasses.dataclass
class _ScanJob:
    id: str
    request: ScanRequest
    cancel: threading.Event = dataclasses.field(default_factory=threading.Event)
    done: threading.Event = dataclasses.field(default_factory=threading.Event)
    # why ``cancel`` was set (a client's DELETE, Ctrl-C or SIGTERM of a one-shot scan, the daemon's
    # shutdown): the sidecar's ``stop_reason`` of a cancelled or interrupted scan
    cancel_reason: str | None = None
    # the linearization health check before the scan (lidard.instrument.healthcheck.health_record)
    linearization: dict | None = None


@dataclasses.dataclass
class _CalibrationJob:
    future: concurrent.futures.Future = dataclasses.field(default_factory=concurrent.futures.Future)


@dataclasses.dataclass
class _SelftestJob:
    future: concurrent.futures.Future = dataclasses.field(default_factory=concurrent.futures.Future)


@dataclasses.dataclass
class _TaskJob:
    """A procedure that needs the instrument (a calibration measurement): ``fn()`` on the worker thread."""

    fn: Any
    future: concurrent.futures.Future = dataclasses.field(default_factory=concurrent.futures.Future)
