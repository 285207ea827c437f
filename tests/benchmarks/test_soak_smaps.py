"""benchmarks/soak_smaps.py: the memory-map samples a soak writes beside it (``soak.py --smaps-dir``), and
the diff that puts a step of a process's RSS in the mapping that grew and the threads that came with it."""

from __future__ import annotations

import json
import mmap
import os
import sys
import threading

import numpy as np
import pytest

from benchmarks import soak, soak_smaps

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

STEP = 24 << 20          # a step of 24 MiB, mapped on its own (mmap: whatever malloc's thresholds are)


def test_a_step_and_a_new_thread_show_in_the_diff(tmp_path, capsys):
    me = os.getpid()
    soak_smaps.write_sample(tmp_path, 0, 0.0, {"bench": [me]})
    # an anonymous mapping of its own: a malloc'd block may come from freed, already-resident heap in a
    # long-lived worker (glibc's dynamic mmap threshold rises to 32 MiB after large frees)
    region = mmap.mmap(-1, STEP)
    block = np.frombuffer(region, np.uint8)
    block[:] = 1                                    # touched: resident
    release = threading.Event()
    t = threading.Thread(target=release.wait, name="held")
    t.start()
    try:
        soak_smaps.write_sample(tmp_path, 1, 20.0, {"bench": [me]})
        assert soak_smaps.main([str(tmp_path), "--role", "bench", "--min-kb", "4096"]) == 0
    finally:
        release.set()
        t.join()
    out = capsys.readouterr().out
    lo, hi = block.ctypes.data, block.ctypes.data + STEP
    moved = [line.split() for line in out.splitlines() if line.strip().startswith(("new", "grew"))]
    # the block's mapping (numpy's huge-page advice may split it in two) is reported, all of it resident
    hits = [f for f in moved if int(f[1].split("-")[0], 16) < hi and int(f[1].split("-")[1], 16) > lo]
    assert hits, out
    assert sum(int(f[f.index("->") + 1]) for f in hits) >= STEP // 1024 - 4, hits
    assert f"({t.native_id}, " in out.split("threads new")[1].split("gone")[0], out
    sample = json.loads((tmp_path / "00001.json").read_text())
    assert sample["t_s"] == 20.0 and sample["processes"]["bench"][0]["pid"] == me


def test_a_process_gone_is_an_empty_sample(tmp_path):
    soak_smaps.write_sample(tmp_path, 0, 1.0, {"bench": [2 ** 22 + 12345]})   # above pid_max's default
    proc = json.loads((tmp_path / "00000.json").read_text())["processes"]["bench"][0]
    assert proc["maps"] == [] and proc["threads"] == []


def test_soak_refuses_a_sampling_period_that_is_not_positive(capsys):
    with pytest.raises(SystemExit) as exc:
        soak.main(["--smaps-every", "0", "--smaps-dir", "/nonexistent"])
    assert exc.value.code == 2 and "--smaps-every must be > 0" in capsys.readouterr().err
