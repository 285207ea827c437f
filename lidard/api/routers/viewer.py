"""The web viewer (GET /, static files under /viewer/) and the incremental points it draws.

``GET /scans/{id}/points/live?since=N`` answers the points of a scan from index ``N`` on, while it
runs (from the worker's :class:`lidard.live.points.LivePoints`) and after it ended (the buffer, or
the scan's file once the buffer has moved on), in the float32 layout of
:func:`lidard.live.points.encode_points`. Headers say where the slice starts, how many points the
scan has so far and whether that count is final, so the page appends without re-reading.
The page and its scripts ship inside the package (``lidard/api/viewer/static``); nothing is
fetched from the network at run time (three.js is vendored, see docs/viewer.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request, Response, status
from fastapi.responses import FileResponse

from ...live.points import LIVE_FIELDS, LivePoints, LiveSlice, encode_points
from ...outputs import read_points
from ..deps import StoreDep

STATIC_DIR = Path(__file__).resolve().parent.parent / "viewer" / "static"
MAX_LIVE_POINTS = 200_000

router = APIRouter(tags=["viewer"])


@router.get("/", response_class=FileResponse, include_in_schema=False)
def index() -> FileResponse:
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html",
                        headers={"Cache-Control": "no-cache"})


def _from_files(store, rec) -> LiveSlice:
    for fmt in ("npz", "ply", "las"):  # the lossless ones first
        if fmt in rec.files:
            pts = read_points(store.data_dir / rec.files[fmt])
            return LiveSlice(pts, 0, len(pts), True)
    return LiveSlice(np.zeros(0), 0, 0, rec.terminal)


@router.get("/scans/{scan_id}/points/live", response_class=Response,
            responses={200: {"content": {"application/octet-stream": {}},
                             "description": "float32 little-endian, fields in X-Lidard-Fields order"},
                       404: {"description": "no scan with this id"}})
def live_points(scan_id: str, request: Request, store: StoreDep,
                since: int = Query(0, ge=0, description="index of the first point wanted"),
                limit: int = Query(MAX_LIVE_POINTS, ge=1, le=MAX_LIVE_POINTS)) -> Response:
    """The scan's points from ``since`` on (at most ``limit``), measured so far."""
    rec = store.get_scan(scan_id)
    if rec is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"scan {scan_id!r} not found")
    live: LivePoints = request.app.state.live
    sl = live.since(scan_id, since)
    if sl is None:
        sl = _from_files(store, rec)
        sl = LiveSlice(sl.points[since:], min(since, sl.total), sl.total, sl.complete)
    pts = sl.points[:limit]
    return Response(encode_points(pts), media_type="application/octet-stream", headers={
        "X-Lidard-Start": str(sl.start), "X-Lidard-Count": str(len(pts)), "X-Lidard-Total": str(sl.total),
        "X-Lidard-Complete": "true" if (sl.complete and sl.start + len(pts) >= sl.total) else "false",
        "X-Lidard-Fields": ",".join(LIVE_FIELDS), "Cache-Control": "no-cache"})
