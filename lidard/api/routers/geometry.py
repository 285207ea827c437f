"""Range scale/zero, pointing and I/Q calibrations over REST, and every calibration's record.

Range: ``POST /calibration/range/plates`` measures the plate now in front of the sensor at the given
known distance (queued like a scan; the measurement is kept in the store); ``GET`` lists the pending
plates, ``DELETE`` (all, or one by id) drops them; ``POST /calibration/range/fit`` fits them and stores
the record (a refused fit answers 422 naming the plate to check, the plates are kept).
Pointing: ``POST /calibration/pointing`` with the known target geometry scans and fits.
I/Q (``adc.iq``): ``POST /calibration/iq`` scans the centre region and fits the receiver's imbalance.
Guided (simulated bench, unattended): ``POST /calibration/run`` places the plates and the sphere
target through the bench, measures, fits both and puts the scene back (lidard.jobs.guided; what
``lidarctl calibrate`` does step by step with progress). Pending plates of an earlier run are refused
unless ``pending`` says ``keep`` or ``drop``. On real hardware 409: a person moves the plate
(``lidarctl calibrate`` asks for each position).
Records: ``GET /calibration/records`` (range, pointing and linearization, newest first) and
``GET /calibration/records/{id}``. The domain functions are :mod:`lidard.jobs.calibrations`.

The request/response models live here, not in ``schemas.py``: they belong to this resource only.
"""

from __future__ import annotations

import asyncio
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Query, status
from pydantic import BaseModel, ConfigDict, Field

from ...instrument.calibration.range import CalibrationRefused
from ...jobs import JobFailed, describe_error
from ...jobs import calibrations as cal
from ..deps import ConfigDep, StoreDep, WorkerDep

router = APIRouter(prefix="/calibration", tags=["calibration"])

REFUSED: dict[int | str, dict[str, Any]] = {422: {"description": "the calibration was refused (too few or inconsistent measurements; named)"},
           503: {"description": "a device fault stopped the measurement, or the queue is full"}}


class PlateIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    # strict: lax coercion would take ``true`` for 1.0 (as ScanCreate's numbers)
    known_m: float = Field(gt=0, le=1000, strict=True,
                           description="distance of the plate plane z = known_m from the lens, m")


class PointingIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    geometry: dict[str, Any] = Field(description="the geometry file's structure: [[sphere]] centre, radius; "
                                                 "[[plane]] point, normal (sensor frame, m)")


class IqIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    max_range_m: float = Field(default=2.0, gt=0, le=1000, strict=True,
                               description="range gate of the calibration scan: the targets whose beats are used lie inside it")


class PlateOut(BaseModel):
    """A pending plate measurement (lidard.instrument.calibration.range.PlateMeasurement)."""

    id: str
    created: float
    known_m: float
    known_range_m: float = Field(description="mean of known_m / d_z over the pixels: the true ray ranges")
    raw_range_m: float = Field(description="mean measured range, zero offset not removed")
    sem_m: float = Field(description="standard error of raw_range_m")
    pixel_std_m: float = Field(description="spread of the single pixels about the plate (range noise)")
    n: int
    delay_s: float = Field(description="the monitor delay the chirp was linearized against")
    temperature_c: float | None = None
    linearization_id: str | None = None


class RecordOut(BaseModel):
    id: str
    kind: Literal["range", "pointing", "iq", "linearization"]
    created: float | None
    temperature_c: float | None
    inputs: dict[str, Any]
    fitted: dict[str, Any]
    residuals: dict[str, Any]


class GuidedIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    pending: Literal["keep", "drop"] | None = Field(
        default=None, description="plates left pending by an earlier run: keep them in this fit or drop them "
                                  "(without: refused, 422, listing them)")
    plates_m: list[float] | None = Field(default=None, min_length=2, max_length=20,
                                         description="plate distances along the optical axis, m (default 0.8, 1.1, 1.4)")


class GuidedOut(BaseModel):
    range: RecordOut
    pointing: RecordOut
    plates: list[dict[str, Any]]
    kept_pending: list[dict[str, Any]]
    wall_s: float


class Removed(BaseModel):
    removed: int


async def _wait(submit) -> Any:
    future = submit()   # CalibrationRefused: 422; QueueFull, WorkerStopped: 503 with Retry-After
    try:
        return await asyncio.wrap_future(future)
    except CalibrationRefused:
        raise
    except Exception as exc:
        raise JobFailed(f"calibration failed: {describe_error(exc)}") from exc


def _clean(d: dict[str, Any]) -> dict[str, Any]:
    t = d.get("temperature_c")
    return {**d, "temperature_c": t if isinstance(t, float) and t == t else None}


@router.post("/range/plates", response_model=PlateOut, status_code=status.HTTP_201_CREATED, responses=REFUSED)
async def add_plate(body: PlateIn, worker: WorkerDep) -> PlateOut:
    """Measure the plate now at ``known_m`` (centre pixels); the measurement waits for the fit."""
    return PlateOut.model_validate(_clean(await _wait(lambda: cal.add_plate(worker, body.known_m))))


@router.get("/range/plates", response_model=list[PlateOut])
def list_plates(store: StoreDep) -> list[PlateOut]:
    return [PlateOut.model_validate(_clean(m)) for m in cal.plates(store)]


@router.delete("/range/plates", response_model=Removed)
def drop_plates(store: StoreDep) -> Removed:
    return Removed(removed=cal.remove_plates(store))


@router.delete("/range/plates/{plate_id}", response_model=Removed,
               responses={404: {"description": "no pending plate measurement with this id"}})
def drop_plate(plate_id: str, store: StoreDep) -> Removed:
    n = cal.remove_plates(store, [plate_id])
    if n == 0:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no pending plate measurement {plate_id!r}")
    return Removed(removed=n)


@router.post("/range/fit", response_model=RecordOut, status_code=status.HTTP_201_CREATED, responses=REFUSED)
def fit_range(store: StoreDep, cfg: ConfigDep, worker: WorkerDep) -> RecordOut:
    """Fit the pending plates: the effective monitor delay and the zero offset; later scans use them."""
    try:
        return RecordOut.model_validate(cal.fit_range(store, cfg.monitor.delay_s, worker.setup_of("range")).to_dict())
    except CalibrationRefused as exc:
        raise HTTPException(422, str(exc)) from None


@router.post("/pointing", response_model=RecordOut, status_code=status.HTTP_201_CREATED, responses=REFUSED)
async def pointing(body: PointingIn, worker: WorkerDep) -> RecordOut:
    """Scan the known targets and fit the pointing model; later scans use it."""
    rec = await _wait(lambda: cal.pointing(worker, body.geometry))
    return RecordOut.model_validate(rec.to_dict())


@router.post("/iq", response_model=RecordOut, status_code=status.HTTP_201_CREATED, responses=REFUSED)
async def iq(worker: WorkerDep, body: IqIn | None = None) -> RecordOut:
    """Fit the I/Q receiver's gain ratio and phase error on the targets in front of the sensor (adc.iq);
    later scans remove it."""
    body = body or IqIn()
    rec = await _wait(lambda: cal.iq(worker, body.max_range_m))
    return RecordOut.model_validate(_clean(rec.to_dict()))


@router.post("/run", response_model=GuidedOut, status_code=status.HTTP_201_CREATED,
             responses={**REFUSED, 409: {"description": "real hardware: the plate positions need an operator"}})
async def run_guided(worker: WorkerDep, cfg: ConfigDep, body: GuidedIn | None = None) -> GuidedOut:
    """The whole calibration on a simulated bench: range plates, the range fit, then the pointing spheres."""
    from ...jobs.guided import GuidedPlan, bench_scene, run_guided as guided
    body = body or GuidedIn()
    if not worker.instrument.simulated:
        raise HTTPException(status.HTTP_409_CONFLICT, "the instrument is real hardware: a person places the plate "
                            "at each distance; run `lidarctl calibrate`, which asks for each position")
    for d in body.plates_m or ():
        if not (d > 0 and d <= 1000):
            raise HTTPException(422, f"plates_m: {d!r} is not a distance in metres (0 < d <= 1000)")
    plan = GuidedPlan(plates_m=tuple(body.plates_m)) if body.plates_m else GuidedPlan()
    scene = bench_scene(cfg, worker)

    def task():
        try:
            return guided(worker, plan, cfg.monitor.delay_s, pending=body.pending or "refuse")
        finally:   # the bench shows what it showed before
            worker.instrument.set_scene(scene)
    out = await _wait(lambda: worker.submit_task(task))
    return GuidedOut.model_validate({**out, "range": _clean(out["range"]), "pointing": _clean(out["pointing"])})


@router.get("/records", response_model=list[RecordOut])
def records(store: StoreDep, cfg: ConfigDep, kind: Literal["range", "pointing", "iq", "linearization"] | None = None,
            limit: int = Query(20, ge=1, le=200)) -> list[RecordOut]:
    return [RecordOut.model_validate(_clean(r)) for r in cal.records(store, cfg, kind, limit)]


@router.get("/records/{cal_id}", response_model=RecordOut,
            responses={404: {"description": "no calibration record with this id"}})
def record(cal_id: str, store: StoreDep) -> RecordOut:
    rec = cal.record(store, cal_id)
    if rec is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no calibration record {cal_id!r}")
    return RecordOut.model_validate(_clean(rec))
