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
    # no module of the project is silenced wholesale, nor followed without being reported
    ours = {m: f for m, f in flags.items() if m.startswith(("lidard", "drivers", "sim_devices"))}
    assert not any(f.get("ignore_errors") or f.get("follow_imports") in ("silent", "skip") for f in ours.values()), ours


# Signatures past MAX_PARAMS parameters want a parameter object (a frozen dataclass of settings, as
# lidard.dsp.linearize.ilc.IlcSettings, lidard.dsp.detect.cfar.CfarSettings). A ratchet: the count may fall, never rise,
# and none may grow longer than the longest today (compensated_spectrum, pair_up_down_matched, 12). `python benchmarks/static_checks.py
# --long` lists them. Compiled (numba) kernels are not counted: they take flat arrays, no objects.
LONG_SIGNATURES_AT_MOST = 18
LONGEST_SIGNATURE = 12


def test_long_signatures_do_not_grow():
    from benchmarks.static_checks import MAX_PARAMS, long_signatures
    long = long_signatures(ROOT)
    listing = "\n".join(f"{n:3d} {where}" for n, where in long)
    assert len(long) <= LONG_SIGNATURES_AT_MOST, f"more functions take > {MAX_PARAMS} parameters:\n{listing}"
    assert all(n <= LONGEST_SIGNATURE for n, _ in long), listing


def test_the_signature_count_sees_every_kind_of_parameter(tmp_path):
    # positional-only, keyword-only, *args and **kwargs count; self does not; nested functions count
    from benchmarks.static_checks import long_signatures
    pkg = tmp_path / "lidard"
    pkg.mkdir()
    (tmp_path / "drivers").mkdir()
    (tmp_path / "sim_devices").mkdir()
    (pkg / "m.py").write_text(
        "def short(a, b, c, d, e, f, g, h):\n    pass\n\n\n"
        "def nine(a, /, b, c, *args, d, e, f, g, **kw):\n    pass\n\n\n"
        "class C:\n    def method(self, a, b, c, d, e, f, g, h):\n        def inner(a, b, c, d, e, f, g, h, i):\n"
        "            pass\n")
    assert sorted(long_signatures(tmp_path)) == [(9, "lidard/m.py:11 inner"), (9, "lidard/m.py:5 nine")]
