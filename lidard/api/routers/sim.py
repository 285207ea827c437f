"""Simulation only: PUT /sim/scene replaces the bench's scene; /sim/faults injects, lists and clears
bench faults (the catalogue and parameters are those of ``sim_devices.faults``).

On a real instrument every endpoint here answers 409 (the request is fine, the daemon's state, real
hardware, does not allow it): the instrument says so (``simulated`` false, or ``NotSimulated`` from
its simulation methods). A fault the bench refuses (unknown kind, bad parameter) is 422 naming it.
"""

import hashlib
import json
import tomllib
from typing import Any

from fastapi import APIRouter, HTTPException, Query, Request, status
from pydantic import BaseModel, ConfigDict, Field

from ...instrument.errors import NotSimulated
from ...instrument.protocol import Instrument
from ..deps import InstrumentDep
from ..schemas import SceneAccepted

router = APIRouter(prefix="/sim", tags=["simulation"])
MAX_SCENE_BYTES = 1 << 20


@router.put("/scene", response_model=SceneAccepted,
            openapi_extra={"requestBody": {"required": True, "content": {
                "application/toml": {"schema": {"type": "string"}},
                "application/json": {"schema": {"type": "object"}}}}})
async def put_scene(request: Request, instrument: InstrumentDep) -> SceneAccepted:
    """Body: a scene in the TOML format of config/scenes (or the same structure as JSON)."""
    if not instrument.simulated:
        raise _real_hardware("scenes can only be set on a simulated bench")
    body = await request.body()
    if len(body) > MAX_SCENE_BYTES:
        raise HTTPException(status.HTTP_413_REQUEST_ENTITY_TOO_LARGE,
                            f"scene body larger than {MAX_SCENE_BYTES} bytes")
    try:
        text = body.decode("utf-8")
    except UnicodeDecodeError:
        raise HTTPException(422, [{"loc": ["body"], "msg": "scene body is not UTF-8 text",
                                   "type": "value_error"}]) from None
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    try:
        data = json.loads(text) if ctype.endswith("json") else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        kind = "JSON" if ctype.endswith("json") else "TOML"
        raise HTTPException(422, [{"loc": ["body"], "msg": f"<body>: invalid {kind}: {exc}",
                                   "type": "scene_error"}]) from None
    if not data:
        raise HTTPException(422, [{"loc": ["body"], "msg": "<body>: the scene is empty; send at least "
                                   "a name and a [[target]]", "type": "scene_error"}])
    try:
        # the bench parses and checks it (the scene format belongs to the simulator)
        summary = instrument.set_scene(data)
    except NotSimulated:
        raise _real_hardware("scenes can only be set on a simulated bench") from None
    except ValueError as exc:
        raise HTTPException(422, [{"loc": ["body"], "msg": str(exc), "type": "scene_error"}]) from None
    # later sidecars name this scene: it has no file, so the uploaded body's hash identifies it
    worker = getattr(request.app.state, "worker", None)
    if worker is not None:
        worker.base_meta["scene"] = {"path": None, "source": "PUT /sim/scene", "name": summary["name"],
                                     "sha256": hashlib.sha256(body).hexdigest()}
        worker.sim_scene = data   # what a factory calibration puts back once its fixtures are done
    return SceneAccepted(name=summary["name"], targets=summary["targets"])


@router.get("/scene", response_model=dict[str, Any], responses={409: {"description": "real hardware"}})
def get_scene(request: Request, instrument: InstrumentDep) -> dict[str, Any]:
    """The scene the bench shows (the scene-file structure): the last one placed with PUT, else the
    configuration's ``sim.scene``; what a calibration run puts back once its fixtures are done."""
    from ...jobs.guided import bench_scene
    if not instrument.simulated:
        raise _real_hardware("only a simulated bench has a scene")
    return bench_scene(request.app.state.config, request.app.state.worker)


class FaultIn(BaseModel):
    """``{"kind": "<fault kind>", <its parameters>...}``, e.g. ``{"kind": "usb_timeout", "device":
    "digitizer", "n": 2}``; the kinds and parameters are listed in docs/reliability.md."""

    model_config = ConfigDict(extra="allow")
    kind: str = Field(min_length=1, max_length=64)


class FaultList(BaseModel):
    faults: list[dict[str, Any]]


class FaultsCleared(BaseModel):
    cleared: int


def _real_hardware(what: str) -> HTTPException:
    return HTTPException(status.HTTP_409_CONFLICT, f"the instrument is real hardware; {what}")


_NO_BENCH = "faults can only be injected into a simulated bench"


def _require_sim(instrument: Instrument) -> None:
    if not instrument.simulated:
        raise _real_hardware(_NO_BENCH)


def _refused(exc: Exception) -> HTTPException:
    return HTTPException(422, [{"loc": ["body"], "msg": str(exc), "type": "fault_error"}])


@router.post("/faults", response_model=dict[str, Any], status_code=status.HTTP_201_CREATED,
             responses={409: {"description": "real hardware"}, 422: {"description": "unknown kind or bad parameter"}})
def inject_fault(body: FaultIn, instrument: InstrumentDep) -> dict[str, Any]:
    """Inject one fault into the simulated bench; answers the active fault with its ``id``."""
    _require_sim(instrument)
    params = dict(body.model_extra or {})
    try:
        return instrument.inject_fault(body.kind, **params)
    except NotSimulated:
        raise _real_hardware(_NO_BENCH) from None
    except (ValueError, TypeError) as exc:  # SimFaultError is a ValueError
        raise _refused(exc) from None


@router.get("/faults", response_model=FaultList, responses={409: {"description": "real hardware"}})
def list_faults(instrument: InstrumentDep) -> FaultList:
    _require_sim(instrument)
    try:
        return FaultList(faults=instrument.active_faults())
    except NotSimulated:
        raise _real_hardware(_NO_BENCH) from None


@router.delete("/faults", response_model=FaultsCleared,
               responses={409: {"description": "real hardware"}, 422: {"description": "unknown kind"}})
def clear_faults(instrument: InstrumentDep,
                 kind: str | None = Query(None, min_length=1, max_length=64)) -> FaultsCleared:
    """Clear every fault, or only those of ``kind``; normal behaviour is restored (ports reconnect)."""
    _require_sim(instrument)
    try:
        return FaultsCleared(cleared=instrument.clear_faults(kind))
    except NotSimulated:
        raise _real_hardware(_NO_BENCH) from None
    except (ValueError, TypeError) as exc:
        raise _refused(exc) from None
