"""A scan decides its DSP path once, before its first batch, records it, and its replay follows it: the
replay's points are the scan's own, byte for byte, on one core (a small scan below the kernels' break-even
and a large one above it) and from the DSP pool's workers; the recorded path is honoured; a capture
recorded before the path was, or a compiled one replayed without the kernels, still replays and says so.

The scans are of the CAL letters on the embedded simulated bench at 10 m/s: its letter pixels see two
returns (the letter and the wall behind it), the joint two-tone fit's case, where the compiled kernels and
the numpy path agree only to rounding (tests/lidard/raw/test_raw_replay_workers.py shows that they differ
on this region). The points are float32 and show such a difference only now and then, so the float64
frame results behind the scan's points and the replay's are compared too, where the scan ran its DSP in
one call and the replay in one task: the float64 results also move in their last bits with the batch a
pixel is processed in (on either path), which the float32 points do not show here.
"""

from __future__ import annotations

import importlib.util
import shutil
import threading

import numpy as np
import pytest
import zarr

from lidard import dsp_pool
from lidard.dsp.spectrum import jit
from lidard.instrument import ScanRequest
from lidard.instrument import points as inst_points
from lidard.instrument import scan_loop
from lidard.raw import RawCapture, reprocess
from lidard.raw import replay
from tests.helpers.jit_ab import as_a_fresh_process
from tests.helpers.sim_bench import cal_letters_instrument

pytestmark = [pytest.mark.slow,      # an embedded bench's scans, the DSP pool's workers
              pytest.mark.skipif(importlib.util.find_spec("numba") is None,
                                 reason="numba is not installed: the DSP has one path only")]

FIELDS = ("range_m", "velocity_mps", "intensity_v", "snr_db")
REGION = {"pattern": "roi", "rows": (52, 56), "cols": (40, 56), "averages": 3, "max_range_m": 2.0,
          "max_speed_mps": 10.0}


@pytest.fixture(scope="module")
def bench():
    with cal_letters_instrument() as inst:
        yield inst


def _spy(mp: pytest.MonkeyPatch, module) -> list[np.ndarray]:
    """The float64 frame results ``module`` turns into points, call by call (pixels in scan order)."""
    seen: list[np.ndarray] = []
    real = module.frame_points

    def spy(res, *args, **kw):
        seen.append(np.stack([getattr(res, f) for f in FIELDS]))
        return real(res, *args, **kw)

    mp.setattr(module, "frame_points", spy)
    return seen


def _scan(bench, path, cores: int, one_batch: bool = False):
    """A recorded scan on ``cores`` (1: its DSP in this process, as under ``taskset -c 0``; 2: on the DSP
    pool's worker processes; ``one_batch``: its DSP in one call): (result, the float64 results behind its
    points)."""
    with pytest.MonkeyPatch.context() as mp:
        if one_batch:
            mp.setattr(scan_loop, "DSP_MIN_BYTES", scan_loop.BATCH_BYTES)
        mp.setattr(scan_loop, "pool_workers", lambda: cores)
        mp.setattr(dsp_pool, "pool_workers", lambda: cores)
        seen = _spy(mp, inst_points)
        res = bench.run_scan(ScanRequest(**REGION), lambda p: None, threading.Event(), None, raw_path=path)
    return res, np.concatenate(seen, axis=1)


def _replay(path):
    """The capture reprocessed on this thread in one task: (Reprocessed, the float64 results behind its
    points)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(replay, "MIN_TASKS", 1)
        seen = _spy(mp, replay)
        rep = reprocess(path, map_fn=map)
    return rep, np.concatenate(seen, axis=1)


def _same(a, b, float64: bool = True) -> None:
    """The replay ``a``'s points are the scan ``b``'s, byte for byte (and the float64 results behind them,
    where both ran their DSP in one call)."""
    (rep, rep64), (res, res64) = a, b
    assert rep.meta["tasks"] == 1
    assert len(res.points) >= 40 and rep.points.tobytes() == res.points.tobytes()
    if float64:
        np.testing.assert_array_equal(rep64, res64)        # NaN where no return


def _planned_cells(bench) -> int:
    p = scan_loop.plan_scan(bench.cfg, bench.optics, ScanRequest(**REGION))
    return p.dsp.spectrum_cells(p.n_pixels, p.averages) * 2     # recorded raw: its replay counts too


def test_a_small_one_core_scan_stays_on_numpy_and_its_replay_follows_it(bench, tmp_path, monkeypatch):
    as_a_fresh_process(monkeypatch)            # nothing loaded, no cells counted
    path = tmp_path / "raw.zarr"
    scan = _scan(bench, path, cores=1, one_batch=True)
    assert _planned_cells(bench) < jit.LOAD_AFTER_CELLS
    assert scan[0].meta["dsp"]["path"] == "numpy" and RawCapture(path).attrs["dsp_path"] == "numpy"
    assert jit._compiled.cache_info().currsize == 0       # the scan did not load the kernels
    jit.kernels()                               # this process has them now: the replay still takes numpy
    rep = _replay(path)
    _same(rep, scan)
    assert rep[0].meta["dsp"]["path"] == "numpy" and rep[0].meta["dsp_path_recorded"] == "numpy"
    assert "dsp_path_warning" not in rep[0].meta
    # the other path does differ on this capture: following the recorded one is what keeps the bytes
    compiled = _replay_on(path, "compiled")
    assert not np.array_equal(compiled, scan[1], equal_nan=True)


def _replay_on(path, dsp_path: str) -> np.ndarray:
    """The float64 results of a replay whose capture says ``dsp_path`` (a copy, the attribute rewritten)."""
    other = path.parent / f"as-{dsp_path}-{len(list(path.parent.iterdir()))}.zarr"
    shutil.copytree(path, other)
    zarr.open_group(str(other), mode="r+").attrs["dsp_path"] = dsp_path
    return _replay(other)[1]


def test_a_one_core_scan_above_the_break_even_is_compiled_from_its_first_batch(bench, tmp_path, monkeypatch):
    as_a_fresh_process(monkeypatch)
    cells = _planned_cells(bench)
    # the break-even halfway through this scan (a test hook, not a huge scan), and four DSP batches: a
    # scan that counted its cells as it went would change paths part-way
    monkeypatch.setattr(jit, "LOAD_AFTER_CELLS", cells // 2)
    monkeypatch.setattr(scan_loop, "DSP_MIN_BYTES", 64 << 10)
    path = tmp_path / "raw.zarr"
    scan = _scan(bench, path, cores=1)
    assert scan[0].meta["dsp"]["path"] == "compiled" and RawCapture(path).attrs["dsp_path"] == "compiled"
    as_a_fresh_process(monkeypatch)            # a replay in a process that has not loaded the kernels
    rep = _replay(path)
    _same(rep, scan, float64=False)            # four batches against one task
    assert rep[0].meta["dsp"]["path"] == "compiled"


def test_a_scan_on_the_pool_replays_identically_in_process(bench, tmp_path, monkeypatch):
    as_a_fresh_process(monkeypatch)            # this process: nothing loaded (the workers load at start)
    path = tmp_path / "raw.zarr"
    scan = _scan(bench, path, cores=2)
    assert dsp_pool._POOL is not None and len(dsp_pool._POOL.workers) == 2     # the pool ran its DSP
    assert scan[0].meta["dsp"]["path"] == "compiled"      # the workers' kernels are loaded: no cost
    assert jit._compiled.cache_info().currsize == 0       # ... and this process did not load its own
    _same(_replay(path), scan, float64=False)             # the pool's batches against one task


def test_the_recorded_path_is_honoured_and_a_capture_without_one_still_replays(bench, tmp_path, monkeypatch):
    path = tmp_path / "raw.zarr"
    scan = _scan(bench, path, cores=1, one_batch=True)
    _same(_replay(path), scan)
    recorded = scan[0].meta["dsp"]["path"]
    other = "numpy" if recorded == "compiled" else "compiled"
    # a capture that says the other path replays on it (the flipped attribute is followed)
    flipped = _replay_on(path, other)
    assert not np.array_equal(flipped, scan[1], equal_nan=True)
    # recorded before the path was: decide()'s path (compiled where numba is), said in the metadata
    old = tmp_path / "old.zarr"
    shutil.copytree(path, old)
    del zarr.open_group(str(old), mode="r+").attrs["dsp_path"]
    rep, rep64 = _replay(old)
    assert rep.meta["dsp"]["path"] == "compiled" and rep.meta["dsp_path_recorded"] is None
    assert "does not record its DSP path" in rep.meta["dsp_path_warning"]
    np.testing.assert_array_equal(rep64, (_replay_on(path, "compiled")))


def test_a_compiled_capture_replayed_without_the_kernels_runs_numpy_and_says_so(bench, tmp_path, monkeypatch):
    path = tmp_path / "raw.zarr"
    _scan(bench, path, cores=2)       # on the pool: compiled
    assert RawCapture(path).attrs["dsp_path"] == "compiled"
    want = _replay_on(path, "numpy")
    monkeypatch.setenv("LIDARD_DSP_JIT", "0")      # as a machine without numba
    rep, rep64 = _replay(path)
    assert rep.meta["dsp"]["path"] == "numpy" and rep.meta["dsp_path_recorded"] == "compiled"
    assert "replayed on numpy" in rep.meta["dsp_path_warning"]
    np.testing.assert_array_equal(rep64, want)
