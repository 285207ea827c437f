"""schemathesis (4.x) over the daemon's OpenAPI schema, in process against create_app + FakeInstrument.

What counts as a failure: ANY 5xx, including 503. The daemon answers 503 only for its own state
(queue full, shutting down, a device fault), never for bad input, and this run arranges that state
not to happen (a healthy fake instrument, a queue too long to fill), so every 5xx here would be
bad input that escaped validation. Also checked: documented status codes, response bodies against
their schemas, content types, and that schema-violating requests are rejected with a 4xx.

Not checked, on purpose:
- ``positive_data_acceptance``: ``POST /scans`` validates against the device (``first < stop``,
  wire-bonded rows, pixels only with pattern ``pixels``), which JSON Schema cannot express, so a
  schema-valid body may rightly be a 422 naming the field.
- ``allow_header_conformance``: Starlette's 405 lists only the methods of the route it matched.

The control lock is released after every case so that a generated ``POST /control`` does not turn
the rest of the run into 423s.
"""


import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings

from tests.helpers.api import app_client, make_app
from tests.helpers.fakes import FakeInstrument

_APP = {}


class HealthyInstrument(FakeInstrument):
    """The fake plus a self-test that finds nothing stuck (POST /selftest)."""

    def selftest(self, progress=None):
        n_rows, n_cols = self.optics.summary()["pixels"]
        return {"ok": True, "stuck": [], "single_beam_v": 0.5, "partner_row": 0, "partner_col": 0,
                "rows_tested": n_rows, "cols_tested": n_cols, "row_tap_v": [0.5] * n_rows,
                "col_tap_v": [0.5] * n_cols}


@pytest.fixture(scope="module")
def lidard_openapi(tmp_path_factory):
    app = make_app(tmp_path_factory.mktemp("st"), HealthyInstrument(),
                   max_queue=1_000_000, progress_interval_s=0.0)
    _APP["app"] = app
    with TestClient(app) as client:  # runs the lifespan once: store (it holds the data dir), worker
        # from_asgi would run the lifespan a second time on the same data directory, which the
        # store's directory lock rightly refuses: load the schema through this client instead.
        schema = schemathesis.openapi.from_dict(client.get("/openapi.json").json())
        schema.app = _without_lifespan(app)   # each case's client would start another lifespan too
        yield schema


def _without_lifespan(app):
    """The app with its lifespan already running: lifespan events of further clients are answered
    here, everything else reaches the app (its store and worker stay the fixture's)."""
    async def asgi(scope, receive, send):
        if scope["type"] != "lifespan":
            return await app(scope, receive, send)
        while True:
            message = await receive()
            if message["type"] == "lifespan.startup":
                await send({"type": "lifespan.startup.complete"})
            elif message["type"] == "lifespan.shutdown":
                await send({"type": "lifespan.shutdown.complete"})
                return
    return asgi


schema = schemathesis.pytest.from_fixture("lidard_openapi")


# Per operation, schemathesis 4 runs its coverage phase (deterministic cases: every parameter's
# boundary values, missing required fields, wrong types, out-of-schema values; ~1,150 cases over the
# API, independent of max_examples), the schema's examples, then max_examples random fuzzing cases.
# 25 fuzzing cases each (was 50; ~900 over the API) cost ~27 s of CPU instead of ~35 s.
@pytest.mark.slow  # every operation's generated cases (~30 s)
@schema.parametrize()
@settings(max_examples=25, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                                 HealthCheck.function_scoped_fixture])
def test_api_has_no_5xx_and_conforms(case):
    excluded = [schemathesis.checks.positive_data_acceptance, schemathesis.checks.allow_header_conformance]
    try:
        response = case.call_and_validate(excluded_checks=excluded)
        assert response.status_code < 500, (case.operation.label, response.status_code, response.text)
    finally:
        lock = _APP["app"].state.control_lock
        held = lock.holder()
        if held is not None:
            lock.release(held.token)


def test_openapi_documents_the_gates(lidard_openapi):
    """Every mutating operation lists 401/403/413/423; reads do not (they are never locked)."""
    app = _APP["app"]
    paths = app.openapi()["paths"]
    mutating = [(p, m) for p, ops in paths.items() for m in ops if m in ("post", "put", "patch", "delete")]
    assert ("/scans", "post") in mutating and ("/sim/scene", "put") in mutating and ("/control", "post") in mutating
    for p, m in mutating:
        assert {"401", "403", "413", "423"} <= set(paths[p][m]["responses"]), (p, m)
    assert "423" not in paths["/scans"]["get"]["responses"]
    assert "404" in paths["/scans/{scan_id}"]["get"]["responses"]


@pytest.mark.parametrize("body, field", [
    ({"max_range_m": True}, "max_range_m"),      # found by schemathesis: lax mode read true as 1.0
    ({"averages": True}, "averages"),
    ({"averages": 2.0}, "averages"),
    ({"averages": "2"}, "averages"),
    ({"rows": [False, 3], "pattern": "roi"}, "rows"),
    ({"pattern": "pixels", "pixels": [["1", 2]]}, "pixels"),
])
def test_lax_coercions_are_422(tmp_path, body, field):
    inst = FakeInstrument()
    with app_client(tmp_path, inst) as c:
        r = c.post("/scans", json=body)
        assert r.status_code == 422 and field in str(r.json()["detail"])
        assert inst.requests == []
        # the same fields with proper JSON types are accepted
        assert c.post("/scans", json={"pattern": "roi", "rows": [0, 1], "cols": [0, 2], "averages": 2,
                                      "max_range_m": 3}).status_code == 201


@pytest.mark.parametrize("scene", [
    {"target": [{"kind": [1]}]},           # found by the scene fuzzer: an unhashable kind was a 500
    {"target": [{"kind": {"a": 1}}]},
    {"target": "plane"},
    [1, 2],
])
def test_put_scene_odd_json_is_422_not_500(tmp_path, scene):
    inst = FakeInstrument()
    with app_client(tmp_path, inst) as c:
        r = c.put("/sim/scene", json=scene)
        assert r.status_code == 422, r.text
        assert inst.scenes == []
