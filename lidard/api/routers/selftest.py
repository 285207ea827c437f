"""POST /selftest: toggle every FPSA row and column against the monitor tap, report stuck switches.

The self-test (``LidarInstrument.selftest``) needs the optical path, so it is queued behind
the running and waiting scans like a linearization and the request waits for its report. A device
fault during the test answers 503 naming the cause; a stuck switch is a finding, not an error: 200
with ``ok: false`` and the stuck lines.
"""

import asyncio
from typing import Any, Literal

from fastapi import APIRouter
from pydantic import BaseModel

from ...jobs import JobFailed, describe_error
from ..deps import WorkerDep

router = APIRouter(tags=["selftest"])


class StuckSwitch(BaseModel):
    line: Literal["row", "col"]
    index: int
    state: Literal["on", "off"]
    evidence: str = ""


class SelftestReport(BaseModel):
    ok: bool
    stuck: list[StuckSwitch]
    single_beam_v: float | None
    partner_row: int
    partner_col: int
    rows_tested: int
    cols_tested: int
    row_tap_v: list[float]
    col_tap_v: list[float]
    hv_v: float | None = None          # the HV read back during the test, V
    hv_problem: str | None = None      # dark lines explained by an HV below the switches' pull-in


@router.post("/selftest", response_model=SelftestReport,
             responses={503: {"description": "a device fault stopped the self-test, or the queue is full"}})
async def selftest(worker: WorkerDep) -> SelftestReport:
    """Queue a switch self-test behind the jobs already waiting and return its report."""
    future = worker.submit_selftest()   # QueueFull, WorkerStopped: 503 with Retry-After
    try:
        report: dict[str, Any] = await asyncio.wrap_future(future)
    except Exception as exc:
        raise JobFailed(f"self-test failed: {describe_error(exc)}") from exc
    v1 = report.get("single_beam_v")
    clean = {**report, "single_beam_v": v1 if isinstance(v1, float) and v1 == v1 else None}
    return SelftestReport.model_validate(clean)
