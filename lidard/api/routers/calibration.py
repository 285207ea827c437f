"""Chirp linearization (§2.2, ILC through the monitor MZI): run one, read the latest."""

import asyncio

from fastapi import APIRouter, HTTPException, status

from ..deps import ConfigDep, StoreDep, WorkerDep
from ..schemas import CalibrationOut

router = APIRouter(prefix="/calibration", tags=["calibration"])


@router.post("/linearize", response_model=CalibrationOut, status_code=status.HTTP_201_CREATED)
async def linearize(worker: WorkerDep) -> CalibrationOut:
    """Queue a linearization behind the scans already waiting and return its result."""
    future = worker.submit_calibration()
    cal = await asyncio.wrap_future(future)
    return CalibrationOut.from_result(cal)


@router.get("", response_model=CalibrationOut)
def latest(store: StoreDep, cfg: ConfigDep) -> CalibrationOut:
    cal = store.latest_calibration(cfg.laser)
    if cal is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no calibration stored for laser {cfg.laser!r}; POST /calibration/linearize")
    return CalibrationOut.from_result(cal)
