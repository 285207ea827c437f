"""The limit kernel of a frame scan (benchmarks/limit.py, issue 18): sizes and ratio arithmetic."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.limit import _dsp, _synth, run_limit, stage_ratios


def test_limit_does_the_work_of_the_scan_it_describes():
    r = run_limit(5, 3, 800, 400, channels=2, points=7, use_fraction=0.9, chunk_samples=5000)
    assert r["samples"] == 5 * 3 * 800 * 2
    assert r["n_used"] == 360 and r["points"] == 7
    assert all(r["cpu_s"][k] >= 0 for k in r["cpu_s"]) and r["total_wall_s"] > 0


def test_limit_dsp_finds_the_synthesized_tone():
    fs, n_used = 5e6, 400
    rng = np.random.default_rng(1)
    codes = _synth(rng, 4, 800, 1, fs)                       # 4 records = 2 pixels x 2 averages
    assert codes.dtype == np.int16 and codes.shape == (4, 1, 800)
    idx = _dsp(codes, 2, 400, n_used, np.hanning(n_used).astype(np.float32))
    # tones are drawn between 0.05 and 0.4 fs: the peak bin is at least 0.05 n_used, not DC
    assert idx.shape == (2, 2) and np.all(idx >= int(0.05 * n_used) - 1)


def test_stage_ratios():
    r = stage_ratios({"synthesis": 6.0, "dsp": 4.0, "points": 1.0}, {"synthesis": 2.0, "dsp": 1.0, "points": 0.0})
    assert r["synthesis"] == 3.0 and r["dsp"] == 4.0 and "points" not in r
    assert r["total"] == pytest.approx(11.0 / 3.0)
