"""The import directions of ARCHITECTURE.md hold (import-linter contracts in pyproject.toml)."""

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_import_contracts_hold():
    exe = shutil.which("lint-imports")
    cmd = [exe] if exe else [sys.executable, "-m", "importlinter.cli"]
    proc = subprocess.run(cmd + ["--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert "broken" not in out.lower() or "0 broken" in out.lower(), out
    # the daemon side reaches the simulator only through the composition root
    assert "Only the composition root starts the simulator KEPT" in out, out
    # issue 12: raycast builds on the target types, the scene loader on both; no cycle comes back
    assert "No import cycles inside the simulated world KEPT" in out, out
    # issue 12: no two modules or subpackages of lidard import each other (known exceptions listed)
    assert "No import cycles inside lidard KEPT" in out, out


def test_pure_core_has_no_io_imports_even_indirectly_in_source():
    # Belt and braces for the rule "physics and dsp: numpy, scipy, stdlib only; no I/O".
    banned = ("import serial", "import usb", "pymodbus", "fastapi", "import asyncio", "import logging",
              "open(", "time.sleep", "time.time(")
    for pkg in ("lidard/physics", "lidard/dsp"):
        for f in (ROOT / pkg).glob("*.py"):
            text = f.read_text()
            for b in banned:
                assert b not in text, f"{f.relative_to(ROOT)} contains {b!r}"
