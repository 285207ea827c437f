"""Reprocessing a stored scan: a new scan record, linked to the original, from its raw capture.

What ``POST /scans/{id}/reprocess`` and ``lidarctl reprocess`` do, knowing nothing about HTTP: read
the original's raw capture (``scans/<id>/raw.zarr``), run the DSP again (:func:`lidard.raw.reprocess`,
in tasks of consecutive chunks through ``map_fn``), write the new point cloud and its sidecar under the new scan's
directory and record the new scan with ``reprocessed_from`` = the original's id. The sidecar starts
from the original's (profile, chirp, calibration, scene) with the DSP settings actually used.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any
from collections.abc import Callable, Iterable

import numpy as np

from ..errors import UnknownScan
from ..outputs import read_sidecar, suffix_of, write_points
from ..store import ScanRecord, Store
from ..raw.capture import RAW_NAME, RawCapture, RawCaptureError, capture_size_bytes
from ..raw.replay import ReprocessSettings, replay_dsp, reprocess
from ..raw.spectrum import PixelSpectrum, pixel_spectrum


class NoRawCapture(RawCaptureError):
    """The scan was not recorded with ``record_raw`` (or its capture was removed)."""

    http_status = 409


def raw_path(store: Store, scan_id: str) -> Path:
    return store.scan_dir(scan_id) / RAW_NAME


def _original(store: Store, scan_id: str) -> tuple[ScanRecord, Path]:
    rec = store.get_scan(scan_id)
    if rec is None:
        raise UnknownScan(f"scan {scan_id!r} not found")
    path = raw_path(store, scan_id)
    if not (path / "zarr.json").is_file():
        raise NoRawCapture(f"scan {scan_id} has no raw capture (scan it with record_raw: true)")
    return rec, path


def _original_meta(store: Store, rec: ScanRecord) -> dict[str, Any]:
    for rel in rec.files.values():
        try:
            return read_sidecar(store.data_dir / rel)
        except (OSError, ValueError):
            continue
    return {}


def reprocess_scan(store: Store, scan_id: str, settings: ReprocessSettings | None = None, *,
                   formats: tuple[str, ...] | None = None,
                   map_fn: Callable[..., Iterable[np.ndarray]] | None = None) -> ScanRecord:
    """Reprocess scan ``scan_id``; returns the new, finished scan record."""
    orig, path = _original(store, scan_id)
    settings = settings or ReprocessSettings()
    replay_dsp(RawCapture(path).attrs, settings)   # a bad override is refused before any record exists
    fmts = tuple(formats or orig.request.get("formats") or ("ply",))
    # the new scan has no capture of its own: reprocess the original again for other settings
    request = {**orig.request, "formats": list(fmts), "record_raw": False, "reprocess": settings.overrides()}
    new = store.create_scan(request, pixels_planned=orig.pixels_planned)
    t0 = time.monotonic()
    store.update_scan(new.id, state="running", stage="reprocessing", started=time.time(),
                      reprocessed_from=scan_id, calibration_id=orig.calibration_id)
    try:
        rep = reprocess(path, settings, map_fn=map_fn)
        wall = time.monotonic() - t0
        partial = bool(orig.partial or not rep.meta["raw_complete"] or rep.meta["pixels"] < orig.pixels_scanned)
        meta = {**_original_meta(store, orig), "dsp": rep.meta["dsp"], "scan_id": new.id,
                "reprocessed_from": scan_id, "request": request,
                "reprocess": {**rep.meta, "wall_s": wall}, "wall_time_s": wall,
                "pixels_scanned": rep.meta["pixels"], "partial": partial}
        files = {}
        for fmt in fmts:
            out = store.scan_dir(new.id) / f"scan{suffix_of(fmt)}"
            write_points(out, rep.points, meta, fmt)
            files[fmt] = str(out.relative_to(store.data_dir))
    except Exception as exc:
        store.update_scan(new.id, state="failed", stage="failed", finished=time.time(),
                          error=f"reprocessing scan {scan_id} failed: {type(exc).__name__}: {exc}",
                          wall_time_s=time.monotonic() - t0)
        raise
    store.update_scan(new.id, state="done", stage="done", progress=1.0, finished=time.time(), files=files,
                      points=int(len(rep.points)), pixels_scanned=int(rep.meta["pixels"]), partial=partial,
                      hardware_time_s=orig.hardware_time_s, wall_time_s=wall)
    done = store.get_scan(new.id)
    if done is None:   # deleted while it was written
        raise UnknownScan(f"scan {new.id} is gone")
    return done


def scan_spectrum(store: Store, scan_id: str, row: int, col: int,
                  settings: ReprocessSettings | None = None) -> PixelSpectrum:
    """One pixel's spectra of a recorded scan (see :func:`lidard.raw.spectrum.pixel_spectrum`)."""
    _, path = _original(store, scan_id)
    return pixel_spectrum(path, row, col, settings)


def raw_size_bytes(store: Store, scan_id: str) -> int:
    return capture_size_bytes(raw_path(store, scan_id))
