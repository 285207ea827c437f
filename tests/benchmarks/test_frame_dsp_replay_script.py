"""benchmarks/frame_dsp_replay.py on two recorded batches: the replay gives FrameDsp.process's own points
(its CPU figure is printed by the script, never asserted) and compare names a differing result."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np

from lidard.dsp.frame import FrameDsp

ROOT = Path(__file__).resolve().parents[2]


def _script():
    spec = importlib.util.spec_from_file_location("frame_dsp_replay", ROOT / "benchmarks" / "frame_dsp_replay.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_replay_gives_the_dsp_points_and_compare_finds_a_difference(tmp_path, capsys):
    mod = _script()
    n = 256
    dsp = FrameDsp(ramp_samples=n, fs_hz=5e6, chirp_rate_hz_per_s=1e14, wavelength_m=1.55e-6, max_range_m=2.0)
    rng = np.random.default_rng(3)
    t = np.arange(2 * n) / dsp.fs_hz
    beats = [np.round(2000 * np.cos(2 * np.pi * f * t) + rng.normal(0, 30, (6, 3, 2 * n))).astype(np.int16)
             for f in (4e5, 7e5)]
    for i, b in enumerate(beats):
        np.save(tmp_path / f"b{i:04d}.npy", b)
        (tmp_path / f"b{i:04d}.json").write_text(json.dumps({"dsp": dsp.to_record(), "lsb_v": 1e-4}))
    out = mod.timed(str(tmp_path), save=str(tmp_path / "a.npz"))
    direct = [dsp.process(b, 1e-4) for b in beats]
    assert out["pixels"] == 12
    assert out["points"] == sum(int(r.present.sum()) for r in direct) > 0
    a = np.load(tmp_path / "a.npz")
    np.testing.assert_array_equal(a["range_m"], np.concatenate([r.range_m for r in direct]))
    moved = {k: a[k].copy() for k in a.files}
    moved["range_m"][0, 0] += 1e-3
    moved["valid"][1, 0] = ~moved["valid"][1, 0]
    np.savez(tmp_path / "b.npz", **moved)
    mod.compare(str(tmp_path / "a.npz"), str(tmp_path / "b.npz"))
    text = capsys.readouterr().out
    assert "valid: 1 entries differ" in text and "present: 0 entries differ" in text
    assert "range_m: finite/non-finite mismatches 0, largest difference 0.001" in text
