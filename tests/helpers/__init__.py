"""Importable test helpers (``from tests.helpers.fakes import FakeInstrument``): pyproject.toml sets
pytest's ``pythonpath = ["."]``, so no test file edits ``sys.path``.

* :mod:`.fakes`: a fake Instrument (synthetic points, held scans, injected failures);
* :mod:`.api`: the daemon's app in process (TestClient) or on a live uvicorn server;
* :mod:`.sim_bench`: a started simulated bench and real drivers on it (fault-injection tests);
* :mod:`.toml_emit`: a minimal TOML writer for the fuzz tests.

Shared fixtures built on these are in tests/conftest.py.
"""
