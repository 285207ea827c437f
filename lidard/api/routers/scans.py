"""Scans: create (queue), list, show, fetch points and their JSON sidecar, cancel, follow progress
(server-sent events)."""

from __future__ import annotations

import asyncio
import json
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Query, Response, status
from fastapi.responses import FileResponse, JSONResponse, StreamingResponse

from ...jobs import UnknownScan
from ...outputs import MEDIA_TYPE, read_sidecar, suffix_of
from ...instrument.plan import ScanPlanError, plan
from ..deps import ConfigDep, InstrumentDep, OpticsDep, StoreDep, WorkerDep
from ..schemas import FileFormat, ScanCreate, ScanList, ScanOut
from .controller import latched_refusal

router = APIRouter(prefix="/scans", tags=["scans"])

# the download's media type per format, declared in the OpenAPI schema as binary bodies
_POINTS_CONTENT = {media: {"schema": {"type": "string", "format": "binary"}} for media in dict.fromkeys(MEDIA_TYPE.values())}
_POINTS_DOC = ("the point file: " + ", ".join(f"{fmt} {media}" for fmt, media in MEDIA_TYPE.items())
               + "; `X-Lidard-Partial: true|false`")


_404: dict[int | str, dict[str, Any]] = {404: {"description": "no scan with this id"}}


def _not_found(scan_id: str) -> HTTPException:
    return HTTPException(status.HTTP_404_NOT_FOUND, f"scan {scan_id!r} not found")


@router.post("", response_model=ScanOut, status_code=status.HTTP_201_CREATED,
             responses={503: {"description": "the queue is full or the daemon is shutting down (Retry-After)"},
                        409: {"description": "a controller fault is latched (names it and `lidarctl faults ack`)"}})
def create_scan(body: ScanCreate, response: Response, worker: WorkerDep, optics: OpticsDep,
                instrument: InstrumentDep, cfg: ConfigDep) -> ScanOut:
    req = body.to_request(cfg.scan)  # fields left out: the configuration's [scan] defaults
    try:
        plan(req, optics)  # validate against the device (bonded rows, array bounds) before queueing
    except ScanPlanError as exc:
        field = str(exc).split(":", 1)[0].split("[", 1)[0]
        raise HTTPException(422, [{"loc": ["body", field], "msg": str(exc), "type": "value_error"}]) from None
    refusal = latched_refusal(instrument)
    if refusal is not None:      # a scan would only fail at bring-up: say what to do instead
        raise HTTPException(status.HTTP_409_CONFLICT, refusal)
    rec = worker.submit_scan(req)   # QueueFull, WorkerStopped: 503 with Retry-After
    response.headers["Location"] = f"/scans/{rec.id}"
    return ScanOut.from_record(rec)


@router.get("", response_model=ScanList)
def list_scans(store: StoreDep, worker: WorkerDep,
               limit: int = Query(100, ge=1, le=1000),
               state: Literal["queued", "running", "done", "failed", "cancelled", "interrupted"] | None = None,
               ) -> ScanList:
    return ScanList(scans=[ScanOut.from_record(r) for r in store.list_scans(limit, state)],
                    queue_length=worker.queue_length(), running=worker.current_scan_id())


@router.get("/{scan_id}", response_model=ScanOut, responses=_404)
def get_scan(scan_id: str, store: StoreDep) -> ScanOut:
    rec = store.get_scan(scan_id)
    if rec is None:
        raise _not_found(scan_id)
    return ScanOut.from_record(rec)


@router.get("/{scan_id}/points", response_class=FileResponse,
            responses={200: {"content": _POINTS_CONTENT, "description": _POINTS_DOC},
                        404: {"description": "unknown scan or format not written"},
                       409: {"description": "scan not finished"}})
def get_points(scan_id: str, store: StoreDep, format: FileFormat = "ply") -> FileResponse:
    rec = store.get_scan(scan_id)
    if rec is None:
        raise _not_found(scan_id)
    if not rec.files:
        if rec.terminal:
            raise HTTPException(status.HTTP_404_NOT_FOUND,
                                f"scan {scan_id} ended {rec.state} without a point cloud")
        raise HTTPException(status.HTTP_409_CONFLICT, f"scan {scan_id} is {rec.state}; points are "
                                                      "available when it is done")
    if format not in rec.files:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"scan {scan_id} has no {format} file; "
                                                       f"written: {', '.join(sorted(rec.files))}")
    path = store.data_dir / rec.files[format]
    if not path.is_file():
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"scan {scan_id}: {format} file is missing from "
                                                       f"the data directory ({rec.files[format]})")
    return FileResponse(path, media_type=MEDIA_TYPE[format], filename=f"{scan_id}{suffix_of(format)}",
                        headers={"X-Lidard-Partial": "true" if rec.partial else "false"})


@router.get("/{scan_id}/sidecar", response_model=dict[str, Any],
            responses={404: {"description": "unknown scan or format not written"}})
def get_sidecar(scan_id: str, store: StoreDep, format: FileFormat = "ply") -> JSONResponse:
    """The JSON sidecar of a written point file: settings, calibration, timing, scene on a bench."""
    rec = store.get_scan(scan_id)
    if rec is None:
        raise _not_found(scan_id)
    if format not in rec.files:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"scan {scan_id} has no {format} file; "
                                                       f"written: {', '.join(sorted(rec.files)) or 'none'}")
    try:
        return JSONResponse(read_sidecar(store.data_dir / rec.files[format]))
    except (OSError, ValueError):
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"scan {scan_id}: the {format} sidecar is missing "
                                                       "or unreadable in the data directory") from None


@router.delete("/{scan_id}", response_model=ScanOut, responses=_404)
def cancel_scan(scan_id: str, worker: WorkerDep) -> ScanOut:
    """Cancel: queued -> cancelled at once; running -> stops, the points so far are kept (partial)."""
    try:
        rec = worker.cancel(scan_id, reason=f"cancelled by a client (DELETE /scans/{scan_id})")
    except UnknownScan:
        raise _not_found(scan_id) from None
    return ScanOut.from_record(rec)


def _sse(event: dict) -> bytes:
    return f"event: {event['event']}\ndata: {json.dumps(event)}\n\n".encode()


@router.get("/{scan_id}/events", response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {}}}, **_404})
async def scan_events(scan_id: str, store: StoreDep, worker: WorkerDep) -> StreamingResponse:
    """Server-sent events: ``progress`` while the scan runs, then one ``end`` and the stream closes.
    The ``end`` event carries the scan's final record (``scan``, as GET /scans/{id} answers it): a
    client that follows a scan while the daemon shuts down gets it before its connection closes."""
    if store.get_scan(scan_id) is None:
        raise _not_found(scan_id)
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue = asyncio.Queue()

    def deliver(ev: dict) -> None:  # called on the worker thread
        try:
            loop.call_soon_threadsafe(queue.put_nowait, ev)
        except RuntimeError:  # the event loop is gone (client or server went away)
            pass

    # Subscribe first, then look at the state: an end that happens in between is still delivered.
    unsubscribe = worker.subscribe(scan_id, deliver)
    rec = store.get_scan(scan_id)
    if rec is not None and rec.terminal:
        queue.put_nowait({"event": "end", "id": scan_id, "state": rec.state, "partial": rec.partial,
                          "error": rec.error})
    elif rec is not None:
        queue.put_nowait({"event": "progress", "id": scan_id, "stage": rec.stage,
                          "pixels_done": rec.pixels_scanned, "pixels_planned": rec.pixels_planned,
                          "points": rec.points, "fraction": rec.progress,
                          "hardware_time_s": rec.hardware_time_s or 0.0})

    async def stream():
        try:
            while True:
                try:
                    ev = await asyncio.wait_for(queue.get(), timeout=15.0)
                except TimeoutError:
                    yield b": keep-alive\n\n"
                    continue
                if ev["event"] == "end":
                    final = store.get_scan(scan_id)
                    if final is not None:
                        ev = {**ev, "scan": ScanOut.from_record(final).model_dump(mode="json")}
                    yield _sse(ev)
                    return
                yield _sse(ev)
        finally:
            unsubscribe()

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache"})
