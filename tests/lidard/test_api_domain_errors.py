"""Each domain error carries its HTTP status, and one exception handler answers it as a problem.

No router maps an error to a status: the class says it (``http_status``, ``retry_after_s``), and
``lidard.api.problems.install`` answers every LidardError with it as an RFC 9457 problem; a device's
error (bare, or wrapped in a DeviceFault) by its place in the tree of drivers.errors.
"""

from __future__ import annotations

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from pydantic import BaseModel, ConfigDict, ValidationError
from typing import Literal

from drivers import errors as de
from drivers.controller.errors import InterlockOpen, LimitError
from drivers.fpsa.errors import NakError, PatternError
from drivers.fpsa.protocol_codes import NakCode
from lidard.api import problems
from lidard.api.control import NotHeld
from lidard.errors import ConfigError, LidardError, UnknownScan, describe_validation
from lidard.instrument.calibration.range import CalibrationRefused
from lidard.instrument.errors import DeviceFault, FaultsStillOpen, NotSimulated, SceneRejected
from lidard.jobs import JobFailed, QueueFull, WorkerStopped
from lidard.raw import PixelNotRecorded, RawCaptureError
from lidard.jobs.reprocess import NoRawCapture

CASES = [
    (UnknownScan("scan 'x' not found"), 404, None),
    (PixelNotRecorded("pixel (1, 2) was not recorded"), 404, None),
    (NoRawCapture("scan x has no raw capture"), 409, None),
    (RawCaptureError("phase_noise=on: no monitor channel"), 422, None),
    (CalibrationRefused("too few plates"), 422, None),
    (FaultsStillOpen(["INTERLOCK_OPEN: interlock open"]), 409, None),
    (NotSimulated("real hardware"), 409, None),
    (SceneRejected("target[0].kind: unknown"), 422, None),
    (NotHeld("nobody holds the lock"), 409, None),
    (QueueFull("queue full (8 jobs)"), 503, "5"),
    (WorkerStopped("daemon shutting down"), 503, "5"),
    (DeviceFault("digitizer", "ARM", TimeoutError("no answer")), 503, None),
    (ConfigError("lab.toml: adc.bits: must be 8"), 503, None),
    (JobFailed("linearization failed: DeviceFault: awg: timeout"), 503, None),
    # a device's error is answered by its place in drivers.errors' tree, wrapped or bare
    (DeviceFault("controller", "write LASER_CURRENT", LimitError("LASER_CURRENT", 900.0, 0.0, 250.0, "mA")),
     422, None),
    (DeviceFault("fpsa", "ARM", NakError("fpsa", "ARM", NakCode.BAD_STATE, None)), 409, None),
    (DeviceFault("controller", "HV on", InterlockOpen("HV on")), 409, None),
    (DeviceFault("fpsa", "ARM", de.CrcError("frame CRC mismatch", device="fpsa", command="ARM")), 503, None),
    (DeviceFault("digitizer", "ARM", de.DeviceTimeout("digitizer", "ARM", attempts=3)), 503, None),
    (InterlockOpen("laser on"), 409, None),
    (PatternError("pixel (3, 4): row 3 is not bonded", index=0, row=3), 422, None),
    (de.DeviceGone("awg", "open", "unplugged"), 503, None),
]


@pytest.fixture(scope="module")
def client() -> TestClient:
    app = FastAPI()
    problems.install(app)
    errors = {str(i): exc for i, (exc, _, _) in enumerate(CASES)}

    @app.get("/raise/{i}")
    def raise_it(i: str) -> None:
        raise errors[i]

    return TestClient(app)


@pytest.mark.parametrize("i", range(len(CASES)), ids=[type(c[0]).__name__ for c in CASES])
def test_a_domain_error_is_answered_with_its_own_status(client, i):
    exc, status, retry = CASES[i]
    r = client.get(f"/raise/{i}")
    assert r.status_code == status
    assert r.headers["content-type"] == problems.PROBLEM_MEDIA_TYPE
    assert r.headers.get("retry-after") == retry
    body = r.json()
    assert body["status"] == status and body["type"] == "about:blank"
    if status < 500 or retry:
        assert body["detail"] == str(exc)          # the refusal says its own message
    else:
        assert body["detail"] == f"{type(exc).__name__}: {exc}"   # the daemon's state, named


def test_only_the_daemons_state_defaults_to_503():
    assert LidardError.http_status == 503
    assert all(isinstance(exc, (LidardError, de.DeviceError)) for exc, _, _ in CASES)


class _Req(BaseModel):
    model_config = ConfigDict(extra="forbid")
    averages: int
    pattern: Literal["raster", "roi"] = "raster"


def _errors(data: dict) -> list:
    with pytest.raises(ValidationError) as ei:
        _Req.model_validate(data)
    return ei.value.errors()


def test_one_wording_for_the_api_and_the_configuration():
    errs = _errors({"averages": "many", "pattern": "spiral", "colour": 1})
    api = describe_validation(errs)
    assert api == ("averages: Input should be a valid integer, unable to parse string as an integer; "
                   "pattern: must be 'raster' or 'roi'; colour: unknown key")
    cfg = describe_validation(errs, source="lab.toml", show_input=True)
    assert cfg.split("; ") == [
        "lab.toml: averages: Input should be a valid integer, unable to parse string as an integer (got 'many')",
        "lab.toml: pattern: must be 'raster' or 'roi' (got 'spiral')",
        "lab.toml: colour: unknown key (got 1)"]


def test_the_body_prefix_and_a_field_already_named_are_not_repeated():
    errs = [{"loc": ("body", "rows"), "msg": "Value error, rows: 40 is past the array", "type": "value_error"},
            {"loc": (), "msg": "Field required", "type": "missing", "input": {}}]
    assert describe_validation(errs) == "rows: 40 is past the array; Field required"
    assert describe_validation(errs, source="s.toml", show_input=True) == (
        "s.toml: rows: 40 is past the array; s.toml: (top level): Field required")
