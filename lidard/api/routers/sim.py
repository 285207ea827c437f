"""PUT /sim/scene: replace the simulated bench's scene (simulation only)."""

import json

from fastapi import APIRouter, HTTPException, Request, status

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
    if not getattr(instrument, "simulated", False):
        raise HTTPException(status.HTTP_409_CONFLICT, "the instrument is real hardware; "
                                                      "scenes can only be set on a simulated bench")
    body = await request.body()
    if len(body) > MAX_SCENE_BYTES:
        raise HTTPException(status.HTTP_413_REQUEST_ENTITY_TOO_LARGE,
                            f"scene body larger than {MAX_SCENE_BYTES} bytes")
    try:
        text = body.decode("utf-8")
    except UnicodeDecodeError:
        raise HTTPException(422, [{"loc": ["body"], "msg": "scene body is not UTF-8 text",
                                   "type": "value_error"}]) from None
    from sim_devices.world.scene import Scene, SceneError  # lazily: only a simulated daemon needs it

    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    try:
        if ctype.endswith("json"):
            try:
                data = json.loads(text)
            except json.JSONDecodeError as exc:
                raise SceneError(f"<body>: invalid JSON: {exc}") from None
            scene = Scene.from_dict(data, source="<body>")
        else:
            import tomllib
            scene = Scene.from_toml_text(text, source="<body>")
            data = tomllib.loads(text)
    except SceneError as exc:
        raise HTTPException(422, [{"loc": ["body"], "msg": str(exc), "type": "scene_error"}]) from None
    instrument.set_scene(data)
    return SceneAccepted(name=scene.name, targets=len(scene))
