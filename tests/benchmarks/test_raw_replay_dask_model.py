"""benchmarks/raw_replay_dask.py: the model's inputs and its three bounds (the formula, not speed)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def mod(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))     # the script imports its sibling raw_replay
    spec = importlib.util.spec_from_file_location("raw_replay_dask", ROOT / "benchmarks" / "raw_replay_dask.py")
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


# 4 chunks of 100 pixels, 1 MB each; 10 ms DSP per chunk; in process 0.05 s = 0.04 DSP + 0.01 serial;
# 1 Dask worker 0.09 s = 0.01 serial + 4 x 0.02 per task; 1 ms scheduling per task
R = {"pixels": 400, "chunks": 4, "raw_bytes": 4e6, "inproc_s": 0.05, "chunk_dsp_s": 0.01,
     "dask1_s": 0.09, "sched2_s": 1e-3}


def test_costs_from_the_measurements(mod):
    k = mod.costs(R)
    assert k["f"] == pytest.approx(0.01 / 400) and k["t_task"] == pytest.approx(0.02)
    assert k["px_per_chunk"] == 100 and k["bytes_per_chunk"] == 1e6


def test_model_bounds(mod):
    k = mod.costs(R)
    # tasks: 1000 chunks on 10 workers = serial 2.5 s + 100 rounds x 20 ms
    assert mod.model_s(k, 10, 1000, 1e12) == pytest.approx(0.01 / 400 * 1e5 + 100 * 0.02)
    # scheduler: 1000 chunks x 1 ms once the workers are many
    assert mod.model_s({**k, "f": 0.0}, 10_000, 1000, 1e12) == pytest.approx(1.0)
    # store bandwidth: 1 GB at 0.1 GB/s
    assert mod.model_s(k, 10_000, 1000, 1e8) == pytest.approx(10.0)
    # the 1-worker model reproduces the 1-worker measurement it came from
    assert mod.model_s(k, 1, 4, 1e12) == pytest.approx(R["dask1_s"])
