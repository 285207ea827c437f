"""Chirp linearization (§2.2, ILC through the monitor MZI): run one, read the latest or the last few."""

import asyncio

from fastapi import APIRouter, HTTPException, Query, status

from ...jobs import JobFailed, describe_error
from ..deps import ConfigDep, StoreDep, WorkerDep
from ..schemas import CalibrationOut

router = APIRouter(prefix="/calibration", tags=["calibration"])


@router.post("/linearize", response_model=CalibrationOut, status_code=status.HTTP_201_CREATED,
             responses={503: {"description": "the linearization failed on a device fault (named)"}})
async def linearize(worker: WorkerDep) -> CalibrationOut:
    """Queue a linearization behind the scans already waiting and return its result."""
    future = worker.submit_calibration()
    try:
        cal = await asyncio.wrap_future(future)
    except Exception as exc:  # a device fault during the ILC run: the daemon's state, not a crash
        raise JobFailed(f"linearization failed: {describe_error(exc)}") from exc
    return CalibrationOut.from_result(cal)


@router.get("", response_model=CalibrationOut,
            responses={404: {"description": "no calibration stored for the configured laser yet"}})
def latest(store: StoreDep, cfg: ConfigDep) -> CalibrationOut:
    cal = store.latest_calibration(cfg.laser)
    if cal is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no calibration stored for laser {cfg.laser!r}; POST /calibration/linearize")
    return CalibrationOut.from_result(cal)


@router.get("/history", response_model=list[CalibrationOut])
def history(store: StoreDep, cfg: ConfigDep, limit: int = Query(5, ge=1, le=100)) -> list[CalibrationOut]:
    """The newest ``limit`` calibrations of the configured laser, newest first (the viewer plots
    each one's ILC convergence, rms frequency error per iteration)."""
    return [CalibrationOut.from_result(c) for c in store.list_calibrations(limit, cfg.laser)]
