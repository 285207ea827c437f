"""Range, pointing and I/Q calibrations as daemon procedures: queued on the worker, recorded in the store.

The steps a lab runs (the physics is in lidard.instrument.calibration.range / .pointing):

* ``add_plate(known_m)``: queued behind the jobs waiting; scans the centre region against the plate
  now in front of the sensor, keeps the measurement in the store (pending, survives a restart);
* ``fit_range()``: fits the pending plates (no instrument needed); a refused fit keeps them so the bad
  one can be removed (``remove_plates``) and measured again; an accepted fit is stored as a record and
  consumes them; the next scan or linearization uses it (and re-linearizes: the ILC's target changed);
* ``pointing(geometry)``: queued; scans around the known targets with the range calibration applied,
  fits the pointing model and stores the record;
* ``iq()``: queued; scans the centre region keeping the raw I/Q records and fits the coherent
  receiver's gain ratio and phase error (adc.iq only; lidard.instrument.calibration.iq).

The REST router (lidard.api.routers.geometry) and ``lidarctl calibration`` call these functions; they
know nothing about HTTP. Refusals raise :class:`CalibrationRefused` with the reason.
"""

from __future__ import annotations

import concurrent.futures
import math
from typing import Any

from ..instrument.calibration.range import DEFAULT_NOISE_M, CalibrationRefused, PlateMeasurement, fit_range as _fit
from ..store import CalibrationRecord


def add_plate(worker, known_m: float) -> concurrent.futures.Future:
    """Queue a plate measurement at ``known_m``; the future resolves to the stored pending measurement."""
    known_m = float(known_m)
    if not (math.isfinite(known_m) and known_m > 0):
        raise CalibrationRefused(f"range calibration: known_m must be a positive distance in metres, got {known_m!r}")

    return worker.submit_task(lambda: plate_now(worker, known_m))


def plate_now(worker, known_m: float) -> dict[str, Any]:
    """On the worker thread: measure the plate now at ``known_m`` and keep it pending, tagged with the
    instrument's range set-up (a fit refuses plates of another one)."""
    from ..instrument.calibration.procedures import measure_plate
    lin = worker.current_linearization()
    m = measure_plate(worker.instrument, worker.optics, float(known_m), lin, worker.applied)
    setup = worker.setup_of("range")
    return worker.store.geometry.add_range_measurement({**m.as_dict(), **({"setup": setup} if setup else {})})


def plates(store) -> list[dict[str, Any]]:
    return store.geometry.range_measurements()


def remove_plates(store, ids: list[str] | None = None) -> int:
    return store.geometry.remove_range_measurements(ids)


def fit_range(store, nominal_delay_s: float, setup: dict[str, Any] | None = None) -> CalibrationRecord:
    """Fit the pending plates; store and answer the record (the plates are consumed). ``setup``: the
    instrument's range set-up (``Setup.as_dict()``); plates measured on another one are refused by id."""
    pending = store.geometry.range_measurements()
    if setup is not None:
        alien = [m["id"] for m in pending if (m.get("setup") or {}).get("hash") != setup["hash"]]
        if alien:
            raise CalibrationRefused(f"range calibration: pending plate(s) {', '.join(alien)} were measured on another "
                                     "set-up (laser, chirp, receiver or instruments); drop them "
                                     "(`lidarctl calibration range drop ID`) and measure again")
    modes = sorted({m["phase_noise_compensation"] for m in pending if m.get("phase_noise_compensation")})
    if len(modes) > 1:
        which = "; ".join(f"{mode}: " + ", ".join(f"{m['id']} ({float(m['known_m']):g} m)" for m in pending
                                                  if m.get("phase_noise_compensation") == mode) for mode in modes)
        raise CalibrationRefused(
            "range calibration: the pending plates were measured in both phase-noise compensation modes "
            f"({which}); a record holds one mode and applies to scans in that mode. Set "
            "scan.phase_noise_compensation to the mode of the scans it is for, drop the others' plates "
            "(`lidarctl calibration range drop ID`) and measure them again")
    fit = _fit([PlateMeasurement.from_dict(m) for m in pending], nominal_delay_s)
    temps = [m["temperature_c"] for m in pending if m.get("temperature_c") is not None]
    rec = store.geometry.save(
        "range", temperature_c=sum(temps) / len(temps) if temps else None,
        inputs={"measurements": pending, **({"setup": setup} if setup else {}),
                **({"phase_noise_compensation": modes[0]} if modes else {})},
        fitted=fit.fitted(), residuals=fit.residuals())
    store.geometry.remove_range_measurements([m["id"] for m in pending])
    return rec


def pointing(worker, geometry: dict[str, Any]) -> concurrent.futures.Future:
    """Queue a pointing calibration against ``geometry`` (the geometry file's structure); the future
    resolves to the stored record. Needs a range calibration first (the fit places points with ranges)."""
    from ..instrument.calibration.pointing import parse_geometry
    surfaces = parse_geometry(geometry, source="<request>")
    return worker.submit_task(lambda: pointing_now(worker, surfaces))


def pointing_now(worker, surfaces) -> CalibrationRecord:
    """On the worker thread: scan the known targets ``surfaces`` (parsed geometry), fit, store the record."""
    from ..instrument.calibration.procedures import measure_pointing
    applied = worker.apply_geometry()
    rng = worker.store.geometry.get(applied.range_id) if applied.range_id else None
    if rng is None:   # refused before any linearization or scan
        raise CalibrationRefused("pointing calibration: no range calibration yet (of this set-up); the fit places points "
                                 "with range-calibrated ranges: run `lidarctl calibrate` (or `lidarctl calibration "
                                 "range add/fit`) first")
    lin = worker.current_linearization()
    # the plates' single-pixel spread: the range noise the point-to-surface residuals are judged by
    noise_m = float(rng.residuals.get("pixel_std_m") or DEFAULT_NOISE_M)
    fit, scan = measure_pointing(worker.instrument, worker.optics, surfaces, lin, noise_m)
    return worker.store.geometry.save(
        "pointing", temperature_c=worker.instrument.laser_temperature_c(),
        inputs={"geometry": [s.as_dict() for s in surfaces], "range_calibration_id": rng.id,
                "linearization_id": lin.meta.get("id"), "noise_m": noise_m, **scan,
                **_setup(worker, "pointing")},
        fitted=fit.fitted(), residuals=fit.residuals())


def iq(worker, max_range_m: float = 2.0) -> concurrent.futures.Future:
    """Queue an I/Q imbalance calibration on the targets in front of the sensor; the
    future resolves to the stored record."""
    from ..instrument.calibration.iq import measure_iq, require_iq_receiver
    max_range_m = float(max_range_m)
    if not (math.isfinite(max_range_m) and max_range_m > 0):
        raise CalibrationRefused(f"I/Q calibration: max_range_m must be a positive distance, got {max_range_m!r}")
    require_iq_receiver(worker.instrument)     # refused before anything is queued

    def task() -> CalibrationRecord:
        worker.apply_geometry()
        lin = worker.current_linearization()
        fit, scan = measure_iq(worker.instrument, worker.optics, lin, max_range_m=max_range_m)
        return worker.store.geometry.save(
            "iq", temperature_c=worker.instrument.laser_temperature_c(),
            inputs={"linearization_id": lin.meta.get("id"), **scan, **_setup(worker, "iq")},
            fitted=fit.fitted(), residuals=fit.residuals())
    return worker.submit_task(task)


def _setup(worker, kind: str) -> dict[str, Any]:
    setup = worker.setup_of(kind)
    return {"setup": setup} if setup else {}


def records(store, cfg, kind: str | None = None, limit: int = 20) -> list[dict[str, Any]]:
    """Range, pointing and I/Q records and the chirp linearizations, newest first, as one listing."""
    out: list[dict[str, Any]] = []
    if kind in (None, "range", "pointing", "iq"):
        out += [r.to_dict() for r in store.geometry.recent(kind, limit)]
    if kind in (None, "linearization"):
        out += [linearization_record(c) for c in store.list_calibrations(limit, cfg.laser)]
    return sorted(out, key=lambda r: r["created"] or 0.0, reverse=True)[:limit]


def linearization_record(cal) -> dict[str, Any]:
    """A chirp linearization in the records' shape (its own table keeps more: the drive waveform)."""
    return {"id": cal.meta.get("id"), "kind": "linearization", "created": cal.meta.get("created"),
            "temperature_c": cal.temperature_c, "inputs": {"laser": cal.laser},
            "fitted": {"mzi_delay_s": cal.meta.get("mzi_delay_s"), "converged": bool(cal.converged)},
            "residuals": {"reduction": cal.reduction, "iterations": cal.iterations}}


def record(store, cal_id: str) -> dict[str, Any] | None:
    rec = store.geometry.get(cal_id)
    if rec is not None:
        return rec.to_dict()
    lin = store.get_calibration(cal_id)
    return None if lin is None else linearization_record(lin)
