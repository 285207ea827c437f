"""benchmarks/raw_replay.py on a 16-pixel ROI: it runs, replays identically, and its figures add up
(the numbers themselves are speed figures: printed by the script, never asserted)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow  # an embedded bench and a chirp linearization first (~7 s)
def test_raw_replay_script_small_roi():
    spec = importlib.util.spec_from_file_location("raw_replay", ROOT / "benchmarks" / "raw_replay.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    r = mod.run([40, 42], [40, 48], averages=1, workers=1, repeat=1, phase_noise="off")
    assert r["pixels"] == 16 and r["identical"] is True and r["chunks"] == 1
    assert r["raw_mb"] * 1e6 > 16 * 2 * r["pixels"]         # at least one int16 sample pair per pixel
    assert all(r[k] > 0 for k in ("scan_s", "scan_raw_s", "replay_s", "pool_s", "hardware_s"))
