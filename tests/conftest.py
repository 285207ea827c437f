"""Suite-wide checks and fixtures.

Fixtures: ``make_client`` builds the daemon's app around an instrument (a FakeInstrument unless
given) and returns an entered TestClient, closed after the test; helpers the fixtures build on are
in the importable package tests/helpers.

The test toolchain is pinned in pyproject.toml (``[project.optional-dependencies] test``) because
plugins break across minor releases of pytest (schemathesis 4.32.5 under pytest 9.2 fails deep inside
one test with ``'Function' object has no attribute '_nodeid'``). A drifted environment is refused at
start-up with one line naming the package, the pin and what is installed.

Nominal bench by default (issue 13): the simulated bench hides tolerances (``[sim.tolerances]``,
on in config/sim.toml: an uncalibrated lab), and most accuracy tests assume a bench that matches
the configuration. ``pytest_configure`` sets ``LIDARD__SIM__TOLERANCES__ENABLED=false`` for the
session (module- and session-scoped fixtures are built before any function fixture) and the autouse
fixture ``_nominal_bench`` again for every test; every ``load_config`` that reads os.environ applies
it and every child bench or daemon a test starts inherits it. A test that passes its own
``environ=`` to ``load_config`` gets nothing from os.environ: it adds
``tests.helpers.tolerances.NOMINAL_ENV``. Opt in with the marker ``@pytest.mark.tolerances``: the
configuration's tolerances (on unless it says otherwise); such a test may set further
``LIDARD__SIM__TOLERANCES__*`` variables with monkeypatch.

No factory calibration: a one-shot ``lidarctl scan --sim`` (and a daemon's first scan) on a bench
with no range/pointing calibration of its set-up runs the bench's factory calibration first
(``sim.factory_calibration``, lidard.jobs.guided: two linearizations, plates and spheres). With a
private cache per test every such scan would pay it, so ``pytest_configure`` sets
``LIDARD__SIM__FACTORY_CALIBRATION=false`` for the session (daemons and children inherit it); a test of
the factory calibration sets it back to true with monkeypatch (or passes its own ``environ=``).
"""

from __future__ import annotations

import contextlib
import os
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement

_PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"


def pinned_test_requirements() -> list[Requirement]:
    data = tomllib.loads(_PYPROJECT.read_text())
    return [Requirement(r) for r in data["project"]["optional-dependencies"]["test"]]


def toolchain_mismatches(requirements: list[Requirement], version_of=metadata.version) -> list[str]:
    """One message per test dependency whose installed version is outside its pin (or missing)."""
    problems = []
    for req in requirements:
        try:
            installed = version_of(req.name)
        except metadata.PackageNotFoundError:
            problems.append(f"{req.name} is not installed (pyproject.toml asks for {req})")
            continue
        if req.specifier and not req.specifier.contains(installed, prereleases=True):
            problems.append(f"{req.name} {installed} is installed but pyproject.toml pins {req}")
    return problems


def pytest_configure(config: pytest.Config) -> None:
    # the nominal bench for the whole session (each xdist worker runs this too): module- and
    # session-scoped fixtures that build benches run before any function-scoped fixture
    from tests.helpers.tolerances import NOMINAL_ENV

    os.environ.update(NOMINAL_ENV)
    os.environ["LIDARD__SIM__FACTORY_CALIBRATION"] = "false"
    problems = toolchain_mismatches(pinned_test_requirements())
    if problems:
        raise pytest.UsageError(
            "incompatible test toolchain: " + "; ".join(problems)
            + ' (run: pip install -e ".[test]")'
        )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Modules that hold a slow test run first, each module still in one piece (its module-scoped
    fixtures are built once). Under ``pytest -n 2`` (work stealing, below) the long
    tests then start at once, and a worker that runs out of work takes the short ones left in the
    other's queue: the suite ends when its longest test does, not after a tail of slow tests that
    happened to be queued last on one worker."""
    has_slow = {item.nodeid.split("::")[0] for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.nodeid.split("::")[0] not in has_slow)   # stable: order kept within


def pytest_xdist_make_scheduler(config: pytest.Config, log):
    """``pytest -n 2`` schedules by work stealing: xdist's default (``load``) hands each worker a fixed
    share up front, so with the slow modules first one worker could be left with all of them while
    the other idles. An explicit ``--dist loadscope`` / ``loadfile`` / ``loadgroup`` is kept."""
    if config.getvalue("dist") != "load":
        return None
    from xdist.scheduler import WorkStealingScheduling

    return WorkStealingScheduling(config, log)


@pytest.fixture(autouse=True)
def _private_cache_dir(tmp_path_factory, monkeypatch):
    """Every test gets its own $XDG_CACHE_HOME: --sim commands cache calibrations there
    (lidard.store.calcache), and a test must neither see another's nor write to the user's."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("xdg-cache")))
    # and its own $XDG_STATE_HOME: `lidarctl control acquire` stores leases there (lidard.cli.leases)
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path_factory.mktemp("xdg-state")))


@pytest.fixture(autouse=True)
def _nominal_bench(request, monkeypatch):
    """A nominal simulated bench unless the test is marked ``tolerances`` (see the docstring)."""
    from tests.helpers.tolerances import NOMINAL_ENV

    if request.node.get_closest_marker("tolerances") is None:
        for name, value in NOMINAL_ENV.items():
            monkeypatch.setenv(name, value)
    else:
        for name in NOMINAL_ENV:
            monkeypatch.delenv(name, raising=False)


@pytest.fixture
def make_client(tmp_path):
    """``make_client(instrument=None, cfg=None, data_dir=None, client_kw=None, **create_app_kw)``:
    an entered TestClient on the daemon's app (data in ``tmp_path/data`` unless given)."""
    from tests.helpers.api import app_client

    with contextlib.ExitStack() as stack:
        def make(instrument=None, cfg=None, data_dir=None, client_kw=None, **app_kw):
            return stack.enter_context(app_client(tmp_path / "data" if data_dir is None else data_dir,
                                                  instrument, cfg, client_kw, **app_kw))
        yield make
