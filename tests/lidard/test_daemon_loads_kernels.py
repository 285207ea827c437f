"""The daemon loads the frame DSP's compiled kernels at its start, not when its small scans pass the
kernels' break-even (lidard.dsp.spectrum.jit.LOAD_AFTER_CELLS) within the hour: that late load was one
~110 MB jump of the daemon's memory 50 minutes into a 60-minute soak (docs/reliability.md)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.helpers.daemon import start_daemon, stop_daemon

pytest.importorskip("numba")
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

REPO = Path(__file__).resolve().parents[2]

_PROBE = """
import json, sys
from lidard.dsp.spectrum import jit
before = [jit.kernels(1) is not None, "numba" in sys.modules]
from lidard.cli.daemon import _load_dsp_kernels
_load_dsp_kernels()
print(json.dumps({"before": before, "after": [jit.kernels(1) is not None, "numba" in sys.modules]}))
"""


def _probe(jit: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=300, cwd=REPO,
                         env={**os.environ, "LIDARD_DSP_JIT": jit}, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_daemons_kernel_load_makes_one_cell_use_the_compiled_kernels():
    r = _probe("1")
    assert r["before"] == [False, False]        # control: below the break-even, the numpy path, no numba
    assert r["after"] == [True, True]


def test_the_daemons_kernel_load_respects_the_jit_switch():
    assert _probe("0")["after"] == [False, False]


@pytest.mark.slow  # a real daemon and its child bench
def test_a_daemon_loads_numba_at_start_without_a_scan(tmp_path):
    proc, _url = start_daemon(tmp_path / "store", env={"LIDARD_DSP_JIT": "1"})
    try:
        maps = Path(f"/proc/{proc.pid}/maps")       # the daemon's own process, not its children
        deadline = time.monotonic() + 240.0         # a bound for a loaded machine, not a speed target
        loaded = False
        while not loaded and time.monotonic() < deadline and proc.poll() is None:
            loaded = "llvmlite" in maps.read_text()
            if not loaded:
                time.sleep(0.2)                     # polling interval only; the deadline decides
        assert loaded, "the daemon did not load numba's libraries without a scan"
    finally:
        stop_daemon(proc)
