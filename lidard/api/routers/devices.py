"""GET /devices (per-device state) and GET /scanner (FPSA optics figures, Table 4-1)."""

from typing import Any

from fastapi import APIRouter

from ..deps import InstrumentDep
from ..schemas import DeviceList, DeviceStatus

router = APIRouter(tags=["devices"])


@router.get("/devices", response_model=DeviceList)
def devices(instrument: InstrumentDep) -> DeviceList:
    return DeviceList(devices=[DeviceStatus.model_validate(d) for d in instrument.devices()])


@router.get("/scanner")
def scanner(instrument: InstrumentDep) -> dict[str, Any]:
    return instrument.scanner()
