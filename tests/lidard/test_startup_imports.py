"""Start-up of ``lidarctl`` stays light (issue 18): the heavy libraries are imported on first use.

Each command runs in a fresh interpreter that prints the top-level packages it loaded; the test
asserts which ones are absent, never a time (timings are in docs/benchmarks.md, farm-bench).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.helpers.deadlines import WAIT_S
HEAVY = ("scipy", "matplotlib", "foxglove", "mcap", "fastapi", "uvicorn", "tqdm")

_PROBE = """
import contextlib, io, json, sys
from lidard.cli import lidarctl
with contextlib.redirect_stdout(io.StringIO()):
    try:
        lidarctl.main(sys.argv[1:])
    except SystemExit:
        pass
print(json.dumps(sorted({name.split(".")[0] for name in sys.modules})))
"""


def _loaded(*argv: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", _PROBE, *argv], capture_output=True, text=True, timeout=WAIT_S,
                         check=True).stdout
    return set(json.loads(out.strip().splitlines()[-1]))


@pytest.mark.parametrize("argv", [("--help",), ("budget", "--distance", "1")], ids=["help", "budget"])
def test_light_commands_do_not_import_heavy_libraries(argv):
    loaded = _loaded(*argv)
    assert "lidard" in loaded                       # the probe did run the CLI
    assert not loaded & set(HEAVY), f"lidarctl {' '.join(argv)} imported {sorted(loaded & set(HEAVY))}"


def test_the_instrument_and_the_daemon_import_without_scipys_heavy_subpackages():
    # a `--sim` scan imports the composition root (bench included) and the daemon its app before any
    # work: scipy.signal, scipy.stats and scipy.optimize (~1 s together) wait for the procedures that
    # use them (the ILC's Hilbert transform, the range calibration's chi-square, the pointing fit)
    probe = ("import json, sys, lidard.instrument.compose, lidard.api.app, sim_devices.bench.bench\n"
             "print(json.dumps(sorted(m for m in sys.modules if m.startswith('scipy.'))))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=WAIT_S, check=True).stdout
    loaded = set(json.loads(out.strip().splitlines()[-1]))
    assert not loaded & {"scipy.signal", "scipy.stats", "scipy.optimize"}, sorted(loaded)
