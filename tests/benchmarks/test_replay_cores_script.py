"""benchmarks/replay_cores.py's stage-timed replay on a small synthetic capture: the stage-timed tasks
give the replay's points (bytes) and their stages add up to no more than the run (figures themselves
are printed by the script, never asserted)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from lidard.raw import reprocess, task_count
from tests.helpers.raw_capture import write_capture

ROOT = Path(__file__).resolve().parents[2]


def _script():
    spec = importlib.util.spec_from_file_location("replay_cores", ROOT / "benchmarks" / "replay_cores.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_one_core_replay_is_timed_per_stage_and_gives_the_replays_points(tmp_path):
    mod = _script()
    syn = write_capture(tmp_path / "raw.zarr", n_pix=40, chunk_pixels=4)
    ref = reprocess(syn.path, map_fn=map).points
    np.save(str(syn.path) + ".points.npy", ref)
    r = mod.one_core(str(syn.path))
    assert r["identical_to_scan"] is True and r["tasks"] == task_count(syn.path) == 10
    assert set(r["stages"]) == {"open", "read", "dsp", "points"}
    assert sum(s["cpu_s"] for s in r["stages"].values()) <= r["cpu_s"] + 0.01
    np.save(str(syn.path) + ".points.npy", ref[1:])           # the comparison can fail
    assert mod.one_core(str(syn.path))["identical_to_scan"] is False
    d = mod._describe(str(syn.path))
    assert d["samples"] == 40 * 2 * 1024 and d["codec"] == "blosc lz4 bitshuffle" and d["chunks"] == 10


def test_codec_figures_cover_the_three_layouts_and_plain_keeps_every_byte(tmp_path):
    mod = _script()
    syn = write_capture(tmp_path / "raw.zarr", n_pix=16, chunk_pixels=4)
    c = mod.codecs(str(syn.path), repeats=1)
    assert set(c) == {"byte-shuffled", "bit-shuffled", "none"}
    assert c["none"]["ratio"] == 1.0 and 0 < c["bit-shuffled"]["ratio"] < 1 and 0 < c["byte-shuffled"]["ratio"] < 1
