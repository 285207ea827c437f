"""A one-shot ``lidarctl scan --sim`` (linearization, health check, scan, DSP, writing) loads none of
scipy's heavy subpackages: the windows and the analytic signal are numpy's, the OS-CFAR factor is a
bisection (each import costs 0.3-1 s of every scan's start-up), and a scan this small does not make
the DSP load numba (lidard.dsp.spectrum.jit.LOAD_AFTER_CELLS: its load costs more than its kernels would
save). The embedded bench has its own break-even (sim_devices.world.synth_jit: numba once the savings
its synthesis asked for reach LOAD_CPU_S); a cold scan (it linearizes) asks for enough white noise to
pass it (>= 36 M samples at ~25 ns saved each: the numpy path of its counter-based generator costs ~30
ns a sample), so numba may be loaded, exactly when that rule says. The probe
asserts which modules are loaded, never a time (the CPU figures: benchmarks/band_and_cores.py,
docs/measured/27_band_and_cores.md)."""

import json
import os
import subprocess
import sys

import pytest

from lidard.dsp.spectrum.jit import LOAD_AFTER_CELLS
from sim_devices.world.synth_jit import LOAD_CPU_S

pytestmark = pytest.mark.slow

_PROBE = """
import contextlib, io, json, sys
from lidard.cli import lidarctl
with contextlib.redirect_stdout(io.StringIO()):
    code = lidarctl.main(sys.argv[1:])
from lidard.dsp.spectrum import jit
from sim_devices.world import synth_jit
print(json.dumps({"code": code, "scipy": sorted(m for m in sys.modules if m.startswith("scipy.")),
                  "numba": "numba" in sys.modules, "dsp_cells": jit._asked[0], "bench_saved_s": synth_jit._asked[0]}))
"""


def test_a_cold_one_shot_scan_imports_no_scipy_signal_stats_or_optimize(tmp_path):
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}     # cold: it linearizes too
    argv = ["scan", "--sim", "--profile", "fpsa20", "--rows", "0:2", "--cols", "0:4", "--progress", "none",
            "--out", str(tmp_path / "s.ply")]
    out = subprocess.run([sys.executable, "-c", _PROBE, *argv], capture_output=True, text=True, timeout=600,
                         env=env, check=True).stdout
    rep = json.loads(out.strip().splitlines()[-1])
    assert rep["code"] == 0 and (tmp_path / "s.ply").stat().st_size > 0
    assert rep["dsp_cells"] < LOAD_AFTER_CELLS          # the DSP's own rule keeps numpy for a scan this small
    assert rep["numba"] is (rep["bench_saved_s"] >= LOAD_CPU_S)   # loaded by the bench's break-even only
    assert not set(rep["scipy"]) & {"scipy.signal", "scipy.stats", "scipy.optimize", "scipy.interpolate"}, rep["scipy"]
