"""A bench process that serves a daemon (``lidar-sim``) loads its compiled synthesis kernels at its
start, not when its scans pass the kernels' break-even minutes later: that late load was a one-time
jump of ~130 MB of its memory (numba's libraries and code generator) at a time that depended on the
scans (50-445 s into a soak), i.e. growth of a long-running process after its start-up. It loads them
before it serves: loaded beside its serving, the load held the interpreter while a daemon's first
controller reads waited, and on a busy machine they timed out."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("numba")
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

REPO = Path(__file__).resolve().parents[3]


def _fresh(code: str, **env: str) -> dict:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         cwd=REPO, env={**os.environ, **env}, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


_PROBE = """
import json, sys
from sim_devices.world import synth_jit
before = [synth_jit.static_fill(1) is not None, "numba" in sys.modules]
loaded = synth_jit.load_now()
after = [synth_jit.static_fill(1) is not None, synth_jit.turns_to_radians_f32(1) is not None,
         synth_jit.quantize_rows(1) is not None, "numba" in sys.modules]
print(json.dumps({"before": before, "loaded": loaded, "after": after}))
"""


def test_load_now_makes_the_kernels_used_from_the_first_sample():
    r = _fresh(_PROBE, LIDARD_DSP_JIT="1")
    # control: a fresh process below the break-even runs the numpy path and has not loaded numba
    assert r["before"] == [False, False]
    assert r["loaded"] is True
    assert r["after"] == [True, True, True, True]


def test_load_now_respects_the_jit_switch():
    r = _fresh(_PROBE, LIDARD_DSP_JIT="0")
    assert r["loaded"] is False
    assert r["after"] == [False, False, False, False]


@pytest.mark.slow  # starts a lidar-sim process (a few seconds; numba's import in it)
def test_lidar_sim_process_loads_the_kernels_at_start():
    proc = subprocess.Popen([sys.executable, "-m", "sim_devices.bench.bench", "--json",
                             "--config", str(REPO / "config" / "sim.toml")], cwd=REPO,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            env={**os.environ, "LIDARD_DSP_JIT": "1"})
    try:
        assert proc.stdout is not None
        json.loads(proc.stdout.readline())          # its endpoints: it is serving, no scan has run
        # loaded before it serves: a load beside its serving held the interpreter while a daemon's
        # first controller reads waited (they timed out on a busy machine)
        assert "llvmlite" in Path(f"/proc/{proc.pid}/maps").read_text(), \
            "lidar-sim announced its endpoints before loading numba's libraries"
    finally:
        proc.terminate()
        proc.wait(timeout=60)


_AHEAD = """
import json, sys, threading
from sim_devices.world import synth_jit
small = synth_jit.load_ahead(1000)                     # a 16-pixel scan: not worth numba's load
small_loaded = "numba" in sys.modules
big = synth_jit.load_ahead(int(2 * synth_jit.LOAD_CPU_S / synth_jit.SAVED_S_NOISE))
loader = [t.name for t in threading.enumerate() if t.name == "sim-jit-load"]
again = synth_jit.load_ahead(10 ** 9)                  # one load per process
# a read asks before the load is done: it waits for the kernels instead of loading them a second time
# or falling back to numpy; nothing was counted toward the break-even (the ARM counts the scan)
kernel = synth_jit.static_fill(1) is not None
print(json.dumps({"small": small, "small_loaded": small_loaded, "big": big, "loader": loader,
                  "again": again, "kernel": kernel, "asked": synth_jit._asked[0],
                  "alive": [t.name for t in threading.enumerate() if t.name == "sim-jit-load"]}))
"""


def test_load_ahead_loads_for_a_large_scan_only_and_reads_wait_for_it():
    r = _fresh(_AHEAD, LIDARD_DSP_JIT="1")
    assert r["small"] is False and r["small_loaded"] is False
    assert r["big"] is True and r["loader"] == ["sim-jit-load"]
    assert r["again"] is False
    assert r["kernel"] is True and r["alive"] == []
    assert r["asked"] == 0


def test_load_ahead_respects_the_jit_switch():
    r = _fresh(_AHEAD, LIDARD_DSP_JIT="0")
    assert r["big"] is False and r["kernel"] is False and r["loader"] == []


_OPEN = """
import json, sys
from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument
from sim_devices.world import synth_jit
expect = {expect}
inst = open_instrument(load_config("config/sim.toml"), scene_path="config/scenes/empty.toml", bench="embedded",
                       expect=None if expect is None else ScanRequest(**expect), preload={preload})
try:
    # what the instrument's first scan finds: the kernels loaded (a read would not wait), or the numpy
    # path below the break-even with numba not even imported
    r = {{"numba": "numba" in sys.modules, "loaded": synth_jit._reducer.cache_info().currsize == 1,
          "loading": bool(synth_jit._loader) and synth_jit._loader[0].is_alive()}}
finally:
    inst.close()
print(json.dumps(r))
"""
SMALL = {"pattern": "roi", "rows": (40, 42), "cols": (0, 8)}                 # 16 pixels: not worth the load
REGION = {"pattern": "roi", "rows": (40, 72), "cols": (0, 128), "averages": 10, "max_range_m": 2.0}


@pytest.mark.slow  # four fresh processes, each opening a bench (numba's import in one of them)
def test_an_embedded_bench_opened_for_unknown_scans_is_ready_with_its_kernels_loaded():
    # opened without a scan, the bench will serve scans nobody announced (an API user, a calibration):
    # like a lidar-sim process it is returned once its kernels are loaded, so its first scan does not
    # pay numba's one-off load (real hardware would not)
    assert _fresh(_OPEN.format(expect=None, preload=True), LIDARD_DSP_JIT="1") == {"numba": True, "loaded": True, "loading": False}
    # opened for a 16-pixel scan (a one-shot command): the scan alone does not pay for the load
    assert _fresh(_OPEN.format(expect=SMALL, preload=True), LIDARD_DSP_JIT="1")["numba"] is False
    # a one-shot command that runs no scan of its own (a self-test) opens with preload=False: nothing
    assert _fresh(_OPEN.format(expect=None, preload=False), LIDARD_DSP_JIT="1")["numba"] is False
    # ... and LIDARD_DSP_JIT=0 loads nothing either way
    assert _fresh(_OPEN.format(expect=None, preload=True), LIDARD_DSP_JIT="0")["numba"] is False


@pytest.mark.slow  # a fresh process opening a bench
def test_an_embedded_bench_opened_for_a_large_scan_loads_beside_the_set_up():
    # a region scan that pays for the load: it starts as the instrument opens and runs on a thread of
    # its own while the caller sets up (the first read waits for it if it is not done)
    r = _fresh(_OPEN.format(expect=REGION, preload=True), LIDARD_DSP_JIT="1")
    assert r["loaded"] or r["loading"]
