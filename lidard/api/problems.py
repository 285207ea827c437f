"""One error model for every error answer: RFC 9457 problem details (``application/problem+json``).

Every 4xx/5xx the daemon sends, whoever raises it (a route's ``HTTPException``, request validation,
a domain error, the control lock, the body-size middleware, an unknown path), is one JSON object:

``type`` (``about:blank``: the status code says it all), ``title`` (the status phrase), ``status``,
``detail`` (one line naming what is wrong, always a string) and, as RFC 9457 extension members,
``errors`` (422: the field-level list ``[{loc, msg, type}]``) and ``holder`` (423: who holds the lock).

:func:`document` rewrites the OpenAPI schema so that every error response of every operation
carries this body model (:class:`Problem`), declares the bearer security scheme and the
``X-Lidard-Lease`` header on the operations that need them (the app-wide gates of
lidard.api.control, which FastAPI cannot see per route).
"""

from __future__ import annotations

import json
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field
from starlette.exceptions import HTTPException as StarletteHTTPException

from ..errors import LidardError
from ..instrument.errors import DeviceFault
from .schemas import describe_errors

PROBLEM_MEDIA_TYPE = "application/problem+json"


class FieldError(BaseModel):
    loc: list[str | int]
    msg: str
    type: str


class Problem(BaseModel):
    """RFC 9457 problem details; ``errors`` and ``holder`` are this API's extension members."""

    model_config = ConfigDict(extra="allow")
    type: str = Field("about:blank", description="a URI naming the problem type; about:blank = see status")
    title: str = Field(description="the HTTP status phrase")
    status: int = Field(ge=400, le=599)
    detail: str = Field(description="what is wrong, in one line naming the field, device or value")
    errors: list[FieldError] | None = Field(None, description="422: one entry per invalid field")
    holder: str | None = Field(None, description="423: the client that holds the control lock")


def problem_body(status: int, detail: Any, **extra: Any) -> dict[str, Any]:
    if isinstance(detail, list):       # field-level errors (pydantic's, a route's own 422): one line + the list
        extra.setdefault("errors", [{"loc": list(e.get("loc", ())), "msg": str(e.get("msg", "")),
                                     "type": str(e.get("type", ""))} for e in detail if isinstance(e, dict)])
        detail = describe_errors(detail)
    try:
        title = HTTPStatus(status).phrase
    except ValueError:
        title = "Error"
    return {"type": "about:blank", "title": title, "status": status, "detail": str(detail),
            **{k: v for k, v in extra.items() if v is not None}}


def problem(status: int, detail: Any, headers: dict[str, str] | None = None, **extra: Any) -> JSONResponse:
    return JSONResponse(problem_body(status, detail, **extra), status_code=status, headers=headers,
                        media_type=PROBLEM_MEDIA_TYPE)


def problem_bytes(status: int, detail: str) -> bytes:
    """The body of a problem answered by raw ASGI code (the body-size middleware)."""
    return json.dumps(problem_body(status, detail)).encode()


def install(app: FastAPI) -> None:
    """Answer route errors, validation errors and routing errors (404/405) as problem details."""

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        return problem(exc.status_code, exc.detail, headers=getattr(exc, "headers", None))

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        return problem(422, list(exc.errors()))

    @app.exception_handler(LidardError)
    async def domain_error(request: Request, exc: LidardError) -> JSONResponse:
        return domain_problem(exc)

    from drivers.errors import DeviceError   # pure: the device error tree, no driver

    @app.exception_handler(DeviceError)
    async def device_error(request: Request, exc: DeviceError) -> JSONResponse:
        return _answer(device_status(exc) or 503, exc, None)


def device_status(exc: BaseException) -> int | None:
    """The answer to a device's error by its place in the tree of :mod:`drivers.errors` (None for an
    error outside it): refused on the host before anything was sent (``InvalidValue``: a setpoint
    beyond its limits, a pattern the chip cannot show) is the request's fault, 422; the device said
    no (``CommandRefused``) or latched faults block it (``DeviceFaulted``), 409, as the daemon's own
    ``FaultsStillOpen``; a link, codec or settling failure is the instrument's state, 503."""
    from drivers import errors as de

    statuses: dict[type[BaseException], int] = {de.InvalidValue: 422, de.CommandRefused: 409,
                                                de.DeviceFaulted: 409, de.DeviceError: 503}
    return next((statuses[c] for c in type(exc).__mro__ if c in statuses), None)


def domain_problem(exc: LidardError) -> JSONResponse:
    """The problem answering a domain error: its class's ``http_status`` (and ``Retry-After``); a
    :class:`DeviceFault` is answered by the tree of the driver error it wraps (:func:`device_status`)."""
    status = exc.http_status
    if isinstance(exc, DeviceFault):
        status = device_status(exc.cause) or status
    return _answer(status, exc, exc.retry_after_s)


def _answer(status: int, exc: BaseException, retry_after_s: int | None) -> JSONResponse:
    # A refusal of the request (4xx) or a busy queue says its own message; the daemon's state
    # (a device fault, 503) is named with its type.
    headers = None if retry_after_s is None else {"Retry-After": str(retry_after_s)}
    detail = str(exc) if status < 500 or headers else f"{type(exc).__name__}: {exc}"
    return problem(status, detail, headers=headers)


# ------------------------------------------------------------------------------------------ OpenAPI
_PROBLEM_REF = {"$ref": "#/components/schemas/Problem"}
BEARER = "bearerAuth"


def document(schema: dict[str, Any], *, mutating: frozenset[str], lease_header: str, token_set: bool) -> None:
    """Rewrite ``schema`` in place: Problem on every error response, bearer security and the lease
    header on mutating operations."""
    comps = schema.setdefault("components", {})
    schemas = comps.setdefault("schemas", {})
    defs = Problem.model_json_schema(ref_template="#/components/schemas/{model}")
    for name, sub in defs.pop("$defs", {}).items():
        schemas[name] = sub
    schemas["Problem"] = defs
    comps.setdefault("securitySchemes", {})[BEARER] = {
        "type": "http", "scheme": "bearer",
        "description": "the daemon's API token ([daemon] token); needed by POST/PUT/PATCH/DELETE when set"}
    comps.setdefault("parameters", {})["Lease"] = {
        "name": lease_header, "in": "header", "required": False, "schema": {"type": "string"},
        "description": "the control lease from POST /control: needed by mutating requests while a lease is "
                       "held (423 otherwise); any request carrying it renews it"}
    for ops in schema.get("paths", {}).values():
        for method, op in ops.items():
            if not isinstance(op, dict) or "responses" not in op:
                continue
            for code, resp in op["responses"].items():
                if code == "default" or (code[:1] in "45"):
                    resp["content"] = {PROBLEM_MEDIA_TYPE: {"schema": _PROBLEM_REF}}
            if method.upper() in mutating:
                # with a token every mutating call needs it; without one the scheme is optional
                op["security"] = [{BEARER: []}] if token_set else [{BEARER: []}, {}]
                params = op.setdefault("parameters", [])
                if not any(p.get("name") == lease_header for p in params):
                    params.append({"$ref": "#/components/parameters/Lease"})
    for unused in ("HTTPValidationError", "ValidationError"):
        schemas.pop(unused, None)
