"""The import directions of ARCHITECTURE.md hold (import-linter contracts in pyproject.toml).

The contracts are checked through import-linter's Python API (``create_report`` on the options read
from pyproject.toml), not through a console script: a missing or renamed entry point must fail this
test, never turn it into a check that runs nothing and passes."""

import tomllib
from pathlib import Path

from importlinter import configuration as _il_configuration
from importlinter.application import use_cases

ROOT = Path(__file__).resolve().parent.parent


def _report():
    _il_configuration.configure()
    config = str(ROOT / "pyproject.toml")
    # the command line's own entry (it registers the contract types); debug mode raises instead of
    # printing an exception and returning a failure code
    verdict = use_cases.lint_imports(config_filename=config, cache_dir=None, is_debug_mode=True, no_logo=True)
    options = use_cases.read_user_options(config)
    return verdict, use_cases.create_report(options, cache_dir=None)


def test_import_contracts_hold():
    verdict, report = _report()
    assert verdict == use_cases.SUCCESS
    declared = [c["name"] for c in tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]]
    assert not report.could_not_run, report.invalid_contract_options
    checks = {contract.name: check for contract, check in report.get_contracts_and_checks()}
    # every contract declared in pyproject.toml was checked, on a graph that holds the three packages
    assert sorted(checks) == sorted(declared) and len(declared) >= 3
    assert report.module_count > 100 and report.import_count > 100
    broken = {name: check.metadata for name, check in checks.items() if not check.kept}
    assert not broken, broken
    assert not report.contains_failures
    # the daemon side reaches the simulator only through the composition root
    assert "Only the composition root starts the simulator" in checks
    # issue 12: raycast builds on the target types, the scene loader on both; no cycle comes back
    assert "No import cycles inside the simulated world" in checks
    # issue 12: no two modules or subpackages of lidard import each other (known exceptions listed)
    assert "No import cycles inside lidard" in checks
    # the DSP's rooms by concern stand in layers (spectrum at the ground, the frame front ends on top)
    assert "The DSP stands in layers" in checks


def test_pure_core_has_no_io_imports_even_indirectly_in_source():
    # Belt and braces for the rule "physics and dsp: numpy, scipy, stdlib only; no I/O".
    banned = ("import serial", "import usb", "pymodbus", "fastapi", "import asyncio", "import logging",
              "open(", "time.sleep", "time.time(")
    for pkg in ("lidard/physics", "lidard/dsp"):
        for f in (ROOT / pkg).rglob("*.py"):     # the sub-packages too (lidard/dsp/spectrum/, ...)
            text = f.read_text()
            for b in banned:
                assert b not in text, f"{f.relative_to(ROOT)} contains {b!r}"
