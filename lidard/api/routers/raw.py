"""Raw captures of scans: reprocess one into a new scan, one pixel's spectra, remove a capture.

The work is :mod:`lidard.jobs.reprocess`'s; here only HTTP: a scan without a capture answers 409 (it
exists, it was not recorded), an unknown scan 404, an override the capture cannot honour 422.
Reprocessing runs in the request's worker thread, not in the scan queue: it needs no hardware.
"""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Query, status

from ...raw import ReprocessSettings
from ...jobs.reprocess import raw_path, reprocess_scan, scan_spectrum
from ..deps import StoreDep
from ..schemas import EstimatorName, ReprocessCreate, ScanOut, WindowName

router = APIRouter(prefix="/scans", tags=["raw captures"])

_ERRORS: dict[int | str, dict[str, Any]] = {404: {"description": "no scan with this id, or the pixel was not recorded"},
           409: {"description": "the scan has no raw capture (not scanned with record_raw)"},
           422: {"description": "an override the capture cannot honour (e.g. phase_noise on without a monitor channel)"}}


@router.post("/{scan_id}/reprocess", response_model=ScanOut, status_code=status.HTTP_201_CREATED, responses=_ERRORS)
def reprocess(scan_id: str, body: ReprocessCreate, store: StoreDep) -> ScanOut:
    """Run the DSP again on the scan's raw capture; answers the new scan (``reprocessed_from``)."""
    # UnknownScan (404), NoRawCapture (409), RawCaptureError (422): their own status
    rec = reprocess_scan(store, scan_id, body.settings(), formats=tuple(body.formats) if body.formats else None)
    return ScanOut.from_record(rec)


@router.get("/{scan_id}/spectrum", response_model=dict[str, Any], responses=_ERRORS)
def spectrum(scan_id: str, store: StoreDep, row: int = Query(..., ge=0), col: int = Query(..., ge=0),
             estimator: EstimatorName | None = None, pfa: float | None = Query(None, gt=0, lt=0.1),
             window: WindowName | None = None,
             phase_noise: Literal["on", "off"] | None = None) -> dict[str, Any]:
    """One pixel's up/down spectra (V^2), OS-CFAR threshold, searched gate, detections and points."""
    settings = ReprocessSettings(estimator=estimator, pfa=pfa, window=window,
                                 phase_noise=None if phase_noise is None else phase_noise == "on")
    return scan_spectrum(store, scan_id, row, col, settings).to_dict()


@router.delete("/{scan_id}/raw", response_model=ScanOut, responses=_ERRORS)
def delete_raw(scan_id: str, store: StoreDep) -> ScanOut:
    """Remove the scan's raw capture (its point clouds stay); ``raw_bytes`` becomes null."""
    rec = store.get_scan(scan_id)
    if rec is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"scan {scan_id!r} not found")
    if not rec.terminal:
        raise HTTPException(status.HTTP_409_CONFLICT, f"scan {scan_id} is {rec.state}; its capture is still written")
    if not store.remove_raw(scan_id, raw_path(store, scan_id)):
        raise HTTPException(status.HTTP_409_CONFLICT, f"scan {scan_id} has no raw capture")
    return ScanOut.from_record(store.get_scan(scan_id))
