"""The nominal-bench switch of the test session (tests/conftest.py ``_nominal_bench``, issue 13).

``NOMINAL_ENV``: the environment override that turns the simulated bench's hidden tolerances off.
A test that calls ``load_config(..., environ={...})`` with its own dict (which replaces os.environ)
adds it: ``environ={**NOMINAL_ENV, "LIDARD__...": ...}``.
"""

NOMINAL_ENV = {"LIDARD__SIM__TOLERANCES__ENABLED": "false"}
