"""Streams: start (queued on the scan worker like a scan), show (frames so far), stop (DELETE keeps every
finished frame and the partial one), fetch a frame's points or the stream's MCAP file.

A stream's frames are written under the data directory, ``streams/<id>/``: ``frame_NNNNN.<fmt>`` with
its JSON sidecar each, or one ``stream.mcap`` (``formats: ["mcap"]``) with a message per frame.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Request, Response, status
from fastapi.responses import FileResponse
from pydantic import BaseModel, ConfigDict, Field, StrictInt

from ...instrument.frames import pixel_period_s
from ...instrument.types import ScanRequest
from ...jobs.stream_job import StreamJob, StreamRequestError, StreamSpec
from ...live.points import LIVE_FIELDS, encode_points
from ...instrument.plan import ScanPlanError, plan
from ...outputs import MEDIA_TYPE, StreamFormat, read_points, suffix_of
from ..deps import ConfigDep, InstrumentDep, OpticsDep, StoreDep, WorkerDep
from .controller import latched_refusal

router = APIRouter(prefix="/streams", tags=["streams"])


class StreamCreate(BaseModel):
    """POST /streams: a pattern and its frames; ``frames`` null streams until DELETE."""

    model_config = ConfigDict(extra="forbid")
    pattern: Literal["raster", "serpentine", "roi", "track"] = "raster"
    rows: tuple[StrictInt, StrictInt] | None = None
    cols: tuple[StrictInt, StrictInt] | None = None
    averages: StrictInt | None = Field(default=None, ge=1, le=100)
    max_range_m: float | None = Field(default=None, gt=0, le=10_000, allow_inf_nan=False, strict=True)
    # the fastest radial speed to measure (the ADC's Doppler band); null: scan.max_speed_mps
    max_speed_mps: float | None = Field(default=None, gt=0, le=100, allow_inf_nan=False, strict=True)
    frames: StrictInt | None = Field(default=None, ge=1, le=1_000_000)
    frame_rate_hz: float | None = Field(default=None, gt=0, le=10_000, allow_inf_nan=False)
    format: StreamFormat = "ply"
    health_interval_s: float = Field(default=60.0, gt=0, le=86_400)


def _streams(request: Request) -> dict[str, StreamJob]:
    st = request.app.state
    if not hasattr(st, "streams"):
        st.streams = {}
    return st.streams


def _job(request: Request, stream_id: str) -> StreamJob:
    job = _streams(request).get(stream_id)
    if job is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"stream {stream_id!r} not found")
    return job


def stream_dir(store, stream_id: str) -> Path:
    return Path(store.data_dir) / "streams" / stream_id


@router.post("", status_code=status.HTTP_201_CREATED,
             responses={503: {"description": "the queue is full or the daemon is shutting down"},
                        409: {"description": "a controller fault is latched"}})
def create_stream(body: StreamCreate, request: Request, response: Response, worker: WorkerDep,
                  optics: OpticsDep, instrument: InstrumentDep, cfg: ConfigDep, store: StoreDep) -> dict[str, Any]:
    req = ScanRequest(pattern=body.pattern, rows=body.rows, cols=body.cols,
                      averages=body.averages or cfg.scan.averages, max_range_m=body.max_range_m or cfg.scan.max_range_m,
                      max_speed_mps=body.max_speed_mps, formats=(body.format,))
    frame_rate = body.frame_rate_hz if body.frame_rate_hz is not None or body.pattern != "track" else 10.0
    try:
        plan(req if body.pattern != "track" else ScanRequest(pattern="raster", rows=body.rows, cols=body.cols),
             optics)
        spec = StreamSpec(req, frames=body.frames, frame_rate_hz=frame_rate, health_interval_s=body.health_interval_s,
                          pixel_s=pixel_period_s(cfg, req.averages))
        spec.check()
    except (ScanPlanError, StreamRequestError) as exc:
        raise HTTPException(422, [{"loc": ["body", str(exc).split(":", 1)[0]], "msg": str(exc),
                                   "type": "value_error"}]) from None
    refusal = latched_refusal(instrument)
    if refusal is not None:
        raise HTTPException(status.HTTP_409_CONFLICT, refusal)
    job = StreamJob(spec)
    out = stream_dir(store, job.id)
    spec.out = str(out / "stream.mcap") if body.format == "mcap" else str(out)
    meta = dict(getattr(worker, "base_meta", {}) or {})
    worker.submit_task(lambda: job.run(worker, meta))   # QueueFull, WorkerStopped: 503 with Retry-After
    _streams(request)[job.id] = job
    response.headers["Location"] = f"/streams/{job.id}"
    return job.status()


_404: dict[int | str, dict[str, Any]] = {404: {"description": "no stream with this id"}}


@router.get("")
def list_streams(request: Request) -> dict[str, Any]:
    """The streams of this daemon run, newest first (what the web viewer offers to show)."""
    jobs = sorted(_streams(request).values(), key=lambda j: j.created_at, reverse=True)
    running = next((j.id for j in jobs if j.state in ("queued", "running")), None)
    return {"streams": [j.status() for j in jobs], "running": running}


@router.get("/{stream_id}", responses=_404)
def show_stream(stream_id: str, request: Request) -> dict[str, Any]:
    job = _job(request, stream_id)
    return {**job.status(), "frames": list(job.frames)}


@router.delete("/{stream_id}", responses=_404)
def stop_stream(stream_id: str, request: Request) -> dict[str, Any]:
    """Stop after the frame in progress (kept, partial); a finished stream answers as it is."""
    job = _job(request, stream_id)
    job.cancel.set()
    return job.status()


@router.get("/{stream_id}/frames/{index}", responses={404: {"description": "no such stream or frame file"}})
def frame_points(stream_id: str, index: int, request: Request, store: StoreDep):
    job = _job(request, stream_id)
    fmt = job.spec.request.formats[0]
    if fmt == "mcap":
        raise HTTPException(status.HTTP_404_NOT_FOUND, "this stream writes one MCAP file: GET /streams/{id}/mcap")
    path = stream_dir(store, stream_id) / f"frame_{index:05d}{suffix_of(fmt)}"
    if not path.exists():
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"stream {stream_id!r} has no frame {index} (yet)")
    return FileResponse(path, media_type=MEDIA_TYPE[fmt])


@router.get("/{stream_id}/frames/{index}/live", response_class=Response,
            responses={200: {"content": {"application/octet-stream": {}},
                             "description": "float32 little-endian, fields in X-Lidard-Fields order"},
                       404: {"description": "no such stream or frame"}})
def frame_live(stream_id: str, index: int, request: Request, store: StoreDep) -> Response:
    """Frame ``index``'s points in the viewer's layout (GET /scans/{id}/points/live): from memory for
    the newest frames, else from the frame's file."""
    job = _job(request, stream_id)
    if not 0 <= index < len(job.frames):
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"stream {stream_id!r} has no frame {index} (frames done: {len(job.frames)})")
    pts = job.frame_points(index)
    if pts is None:
        fmt = job.spec.request.formats[0]
        path = stream_dir(store, stream_id) / f"frame_{index:05d}{suffix_of(fmt)}"
        if fmt == "mcap" or not path.exists():
            raise HTTPException(status.HTTP_404_NOT_FOUND,
                                f"stream {stream_id!r}: frame {index} is no longer held and has no point file")
        pts = read_points(path)
    return Response(encode_points(pts), media_type="application/octet-stream", headers={
        "X-Lidard-Frame": str(index), "X-Lidard-Count": str(len(pts)), "X-Lidard-Total": str(len(pts)),
        "X-Lidard-Complete": "true", "X-Lidard-Fields": ",".join(LIVE_FIELDS), "Cache-Control": "no-cache"})


@router.get("/{stream_id}/mcap", responses={404: {"description": "no such stream, or not an MCAP stream, or running"}})
def stream_mcap(stream_id: str, request: Request, store: StoreDep):
    """The stream's MCAP file, once the stream has ended (it is renamed into place then)."""
    job = _job(request, stream_id)
    path = stream_dir(store, stream_id) / "stream.mcap"
    if job.spec.request.formats[0] != "mcap" or not path.exists():
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"stream {stream_id!r} has no finished MCAP file")
    return FileResponse(path, media_type=MEDIA_TYPE["mcap"])


def stop_all(app) -> None:
    """Daemon shutdown: every running stream ends after its frame in progress."""
    for job in getattr(app.state, "streams", {}).values():
        job.cancel.set()
