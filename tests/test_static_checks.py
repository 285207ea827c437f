"""ruff and mypy, as configured in pyproject.toml ([tool.ruff], [tool.mypy]), find nothing.

mypy is strict on lidard.physics, drivers and lidard.dsp (but for unannotated functions in its ranging front end),
and at its defaults (plus warn_unused_ignores, strict_equality) on the rest of lidard and on sim_devices.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, capture_output=True, text=True, check=False)


def test_ruff_finds_nothing():
    r = _run("ruff", "check", ".", "--no-cache", "--output-format", "concise")
    assert r.returncode == 0, r.stdout + r.stderr


def test_ruff_runs_the_configured_rules(tmp_path):
    # the project's configuration is the one applied: an unused import and a mutable default are found
    bad = tmp_path / "bad.py"
    bad.write_text("import os\n\n\ndef f(x=[]):\n    return x\n")
    r = _run("ruff", "check", "--no-cache", "--config", str(ROOT / "pyproject.toml"), "--output-format",
             "concise", str(bad))
    assert r.returncode == 1
    assert "F401" in r.stdout and "B006" in r.stdout, r.stdout


@pytest.mark.slow
def test_mypy_finds_nothing():
    r = _run("mypy")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Success: no issues found" in r.stdout


def test_mypy_is_strict_where_the_project_says():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"]
    assert set(cfg["files"]) == {"lidard", "drivers", "sim_devices"}
    flags: dict[str, dict[str, object]] = {}
    for section in cfg["overrides"]:
        for mod in section["module"]:
            flags.setdefault(mod, {}).update({k: v for k, v in section.items() if k != "module"})
    for mod in ("lidard.physics.*", "drivers.*"):
        for flag in ("disallow_untyped_defs", "disallow_any_generics", "check_untyped_defs",
                     "no_implicit_reexport", "disallow_untyped_calls"):
            assert flags[mod].get(flag) is True, (mod, flag)
    for flag in ("disallow_any_generics", "check_untyped_defs", "no_implicit_reexport", "disallow_untyped_defs",
                 "disallow_untyped_calls"):
        assert flags["lidard.dsp.*"].get(flag) is True, flag
    # the modules let off "every function annotated" are the ranging front end's, named one by one
    lax = {m for m, f in flags.items() if m.startswith("lidard.dsp") and f.get("disallow_untyped_defs") is False}
    assert lax <= {"lidard.dsp.ranging.*", "lidard.dsp.*.chain", "lidard.dsp.*.frame", "lidard.dsp.*.estimators",
                   "lidard.dsp.*.dtft"}, lax
    # no module of the project is silenced wholesale
    assert not any(f.get("ignore_errors") for m, f in flags.items() if m.startswith(("lidard", "drivers")))
