"""A client driven only by /openapi.json runs acquire -> scan -> poll -> download on a daemon with an API
token and a held control lease; every error response in the schema has the problem-details body model
and the daemon's error answers satisfy it."""

from __future__ import annotations

import io

import jsonschema
import numpy as np
import pytest

from tests.helpers.fakes import FakeInstrument
from tests.helpers.deadlines import HTTP_S

TOKEN = "s3cret-token"
SMALL = {"pattern": "roi", "rows": [0, 3], "cols": [0, 20], "formats": ["ply", "npz", "ros2"]}


class SchemaClient:
    """Builds each request from the operation's entry in the OpenAPI document and nothing else:
    header parameters it declares are filled from values the client learnt (by parameter name), the
    bearer token is sent where the operation's ``security`` names an http/bearer scheme, and the
    ``Accept`` header lists the media types its 200 response declares."""

    def __init__(self, http, token: str | None):
        self.http, self.token = http, token
        self.spec = http.get("/openapi.json").json()
        self.known: dict[str, str] = {}

    def _resolve(self, obj):
        if "$ref" in obj:
            node = self.spec
            for part in obj["$ref"].lstrip("#/").split("/"):
                node = node[part]
            return node
        return obj

    def call(self, method: str, path: str, path_params=None, query=None, body=None):
        op = self.spec["paths"][path][method.lower()]
        headers = {}
        for p in map(self._resolve, op.get("parameters", [])):
            if p["in"] == "header" and p["name"] in self.known:
                headers[p["name"]] = self.known[p["name"]]
        schemes = self.spec.get("components", {}).get("securitySchemes", {})
        for req in op.get("security", []):
            for name in req:
                s = schemes[name]
                if s["type"] == "http" and s["scheme"] == "bearer" and self.token:
                    headers["Authorization"] = f"Bearer {self.token}"
        ok = op["responses"].get("200") or op["responses"].get("201") or {}
        if ok.get("content"):
            headers["Accept"] = ", ".join(ok["content"])
        url = path.format(**(path_params or {}))
        return self.http.request(method, url, params=query, json=body, headers=headers), ok


@pytest.fixture
def api(make_client):
    return make_client(FakeInstrument(), token=TOKEN, progress_interval_s=0.0)


def test_schema_driven_client_runs_acquire_scan_poll_download(api):
    cl = SchemaClient(api, TOKEN)
    r, _ = cl.call("POST", "/control", body={"client": "schema-client"})
    assert r.status_code == 201
    lease_param = cl._resolve(cl.spec["components"]["parameters"]["Lease"])
    cl.known[lease_param["name"]] = r.json()["lease"]      # what the schema says to send it as

    r, _ = cl.call("POST", "/scans", body=SMALL)
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    api.app.state.worker.wait(sid, 20.0)                   # poll once the worker says it ended
    r, _ = cl.call("GET", "/scans/{scan_id}", {"scan_id": sid})
    assert r.status_code == 200 and r.json()["state"] == "done"

    for fmt in ("ply", "npz", "ros2"):
        r, ok = cl.call("GET", "/scans/{scan_id}/points", {"scan_id": sid}, {"format": fmt})
        assert r.status_code == 200
        media = r.headers["content-type"].split(";")[0]
        assert media in ok["content"]
        assert ok["content"][media]["schema"] == {"type": "string", "format": "binary"}
    with np.load(io.BytesIO(cl.call("GET", "/scans/{scan_id}/points", {"scan_id": sid},
                                    {"format": "npz"})[0].content)) as z:
        assert len(z["points"]) == 60
    r, _ = cl.call("DELETE", "/control")
    assert r.status_code == 200 and r.json()["held"] is False


def test_without_the_declared_header_and_scheme_the_same_calls_are_refused(api):
    # the control for the test above: what the schema supplies is what the daemon needs
    assert api.post("/control", json={"client": "a"}).status_code == 401
    lease = api.post("/control", json={"client": "a"}, headers={"Authorization": f"Bearer {TOKEN}"}).json()["lease"]
    r = api.post("/scans", json=SMALL, headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 423 and r.headers["content-type"] == "application/problem+json"
    assert r.json()["holder"] == "a" and r.json()["status"] == 423
    assert api.post("/scans", json=SMALL, headers={"Authorization": f"Bearer {TOKEN}",
                                                   "X-Lidard-Lease": lease}).status_code == 201


def test_security_and_lease_declared_on_every_mutating_operation_only(api):
    spec = api.get("/openapi.json").json()
    assert spec["components"]["securitySchemes"]["bearerAuth"] == {
        **spec["components"]["securitySchemes"]["bearerAuth"], "type": "http", "scheme": "bearer"}
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            refs = [p.get("$ref") for p in op.get("parameters", [])]
            if method.upper() in ("POST", "PUT", "PATCH", "DELETE"):
                assert op["security"] == [{"bearerAuth": []}], (method, path)   # a token is set
                assert "#/components/parameters/Lease" in refs, (method, path)
            else:
                assert "security" not in op and "#/components/parameters/Lease" not in refs, (method, path)


def test_every_error_response_has_the_problem_body_model(api):
    spec = api.get("/openapi.json").json()
    problem = spec["components"]["schemas"]["Problem"]
    assert {"type", "title", "status", "detail"} <= set(problem["properties"])
    n = 0
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            for code, resp in op["responses"].items():
                if code[0] in "45" or code == "default":
                    n += 1
                    assert resp["content"] == {"application/problem+json": {
                        "schema": {"$ref": "#/components/schemas/Problem"}}}, (method, path, code)
    assert n > 50
    assert "HTTPValidationError" not in spec["components"]["schemas"]


@pytest.mark.parametrize("method, url, body, headers, status", [
    ("GET", "/scans/NOPE", None, {}, 404),
    ("GET", "/no/such/path", None, {}, 404),
    ("POST", "/scans", {"averages": 0}, {"Authorization": f"Bearer {TOKEN}"}, 422),
    ("POST", "/scans", {}, {}, 401),
    ("POST", "/scans", {}, {"Authorization": f"Bearer {TOKEN}", "Origin": "http://evil.example"}, 403),
    ("PUT", "/health", None, {}, 405),
])
def test_error_answers_are_problem_details_that_validate(api, method, url, body, headers, status):
    spec = api.get("/openapi.json").json()
    schema = {**spec["components"]["schemas"]["Problem"], "components": spec["components"]}
    r = api.request(method, url, json=body, headers=headers)
    assert r.status_code == status
    assert r.headers["content-type"] == "application/problem+json"
    doc = r.json()
    jsonschema.validate(doc, schema)   # its $refs resolve inside it: the components are attached
    assert doc["status"] == status and isinstance(doc["detail"], str) and doc["detail"]
    if status == 422:
        assert "averages" in doc["detail"] and doc["errors"][0]["loc"][-1] == "averages"


@pytest.mark.slow   # ~7 s: generating the package (offline) and a live uvicorn server
def test_openapi_python_client_generated_from_the_schema_runs_a_scan(tmp_path, make_client):
    """openapi-python-client (test extra) generates a package from /openapi.json, offline; its own
    functions run acquire -> scan -> poll -> download on a live daemon with a token and a held lease.
    The lease travels as the generated ``x_lidard_lease`` argument, the token through the generated
    ``AuthenticatedClient``: nothing is added by hand."""
    import importlib
    import json
    import subprocess
    import sys

    from lidard.api.app import ApiAccess, WorkerOptions, create_app
    from lidard.config import load_config
    from tests.helpers.api import live_server

    app = create_app(load_config(), instrument=FakeInstrument(), data_dir=tmp_path / "data", access=ApiAccess(token=TOKEN),
                     worker_options=WorkerOptions(progress_interval_s=0.0))
    with live_server(app) as url:
        import httpx
        spec = tmp_path / "openapi.json"
        spec.write_text(json.dumps(httpx.get(url + "/openapi.json", timeout=HTTP_S).json()))
        out = tmp_path / "lidard_client"
        gen = subprocess.run([sys.executable, "-m", "openapi_python_client", "generate", "--path", str(spec),
                              "--output-path", str(out), "--meta", "none"], capture_output=True, text=True,
                             timeout=300)
        assert gen.returncode == 0 and (out / "client.py").is_file(), gen.stdout + gen.stderr
        sys.path.insert(0, str(tmp_path))
        try:
            lc = importlib.import_module("lidard_client")
            acquire = importlib.import_module("lidard_client.api.control.control_acquire_control_post")
            create = importlib.import_module("lidard_client.api.scans.create_scan_scans_post")
            get_scan = importlib.import_module("lidard_client.api.scans.get_scan_scans_scan_id_get")
            points = importlib.import_module("lidard_client.api.scans.get_points_scans_scan_id_points_get")
            models = importlib.import_module("lidard_client.models")
            client = lc.AuthenticatedClient(base_url=url, token=TOKEN)

            lease = acquire.sync(client=client, body=models.ControlAcquire(client="generated"))
            assert isinstance(lease, models.ControlLease) and lease.holder == "generated"
            refused = create.sync(client=client, body=models.ScanCreate.from_dict(SMALL))
            assert isinstance(refused, models.Problem) and refused.status == 423   # the lease is needed
            scan = create.sync(client=client, body=models.ScanCreate.from_dict(SMALL), x_lidard_lease=lease.lease)
            assert isinstance(scan, models.ScanOut), scan
            app.state.worker.wait(scan.id, 20.0)
            done = get_scan.sync(client=client, scan_id=scan.id)
            assert done.state == "done" and done.counts.points == 60
            r = points.sync_detailed(client=client, scan_id=scan.id, format_=models.GetPointsScansScanIdPointsGetFormat("npz"))
            assert r.status_code == 200 and r.headers["content-type"] == "application/x-npz"
            with np.load(io.BytesIO(r.content)) as z:
                assert len(z["points"]) == 60
            missing = get_scan.sync(client=client, scan_id="NOPE")
            assert isinstance(missing, models.Problem) and missing.status == 404 and "NOPE" in missing.detail
        finally:
            sys.path.remove(str(tmp_path))
            for name in [m for m in sys.modules if m == "lidard_client" or m.startswith("lidard_client.")]:
                del sys.modules[name]
