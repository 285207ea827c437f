"""A raw capture's replay is a function of its bytes and its settings: the same points, byte for byte, on
this thread, on one or two fresh worker processes, on the DSP pool's workers, first or second in a process.

The capture is a real one: a 10 m/s region scan of the CAL letters on the embedded simulated bench (48
pixels, 3 averages), whose letter pixels see two returns (the letter and the wall behind it): the joint
two-tone fit's case, where the DSP's compiled kernels and its numpy path agree only to rounding. The points
are float32 and show such a difference only now and then, so each task's float64 DSP results are
compared too (tests.helpers.replay_spy).
"""

from __future__ import annotations

import threading
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

import numpy as np
import pytest

from lidard.instrument import ScanRequest
from lidard.raw import RawCapture, reprocess
from lidard.raw import record as raw_record
from lidard.raw import replay
from lidard.dsp.spectrum import jit
from tests.helpers.jit_ab import as_a_fresh_process, compiled_and_numpy
from tests.helpers.replay_spy import task_points_and_results
from tests.helpers.sim_bench import cal_letters_instrument

pytestmark = pytest.mark.slow      # an embedded bench's scan and three freshly spawned worker processes


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    path = tmp_path_factory.mktemp("replay-workers") / "raw.zarr"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(raw_record, "RAW_CHUNK_BYTES", 64 << 10)       # one pixel a chunk: several tasks
        with cal_letters_instrument() as inst:
            res = inst.run_scan(ScanRequest(pattern="roi", rows=(52, 56), cols=(40, 56), averages=3,
                                            max_range_m=2.0, max_speed_mps=10.0),
                                lambda p: None, threading.Event(), None, raw_path=path)
    return path, res


def _tasks(map_fn, path) -> tuple[np.ndarray, np.ndarray]:
    """Every task of the replay through ``map_fn``, cut as :func:`reprocess` cuts them: (points, float64 results)."""
    cap = RawCapture(path)
    k = replay._chunks_per_task(cap)
    n = -(-cap.n_chunks // k)
    parts = list(map_fn(task_points_and_results, [str(path)] * n, range(n), [k] * n))
    return np.concatenate([p for p, _ in parts]), np.concatenate([r for _, r in parts], axis=1)


def test_the_capture_holds_two_return_pixels_on_which_the_dsp_paths_differ_by_rounding(capture, monkeypatch):
    path, res = capture
    cap = RawCapture(path)
    pts = reprocess(path, map_fn=map).points
    per_pixel = np.unique(pts["row"].astype(np.int64) * 1000 + pts["col"], return_counts=True)[1]
    assert cap.n_pixels == 48 and cap.averages == 3 and cap.n_chunks == 48
    assert (per_pixel == 2).sum() >= 3                 # letter and wall: the joint two-tone fit's pixels
    twin = pts[(pts["valid"] == 1)]["range"]
    assert np.all((np.abs(twin - 0.84) < 0.02) | (np.abs(twin - 0.944) < 0.02))   # the letters' plane, the wall
    if jit._compiled() is None:
        pytest.skip("numba is not installed: the DSP has one path only")
    rep = replay.replay_dsp(cap.attrs)
    beat = cap.chunks(0, cap.n_chunks).channel("beat", cap.channels, cap.averages)
    got, want = compiled_and_numpy(monkeypatch, lambda: rep.dsp.process(beat, rep.lsb_v))
    # the case a replay must not mix: the two paths' float64 results are not the same bits here
    assert not np.array_equal(got.velocity_mps, want.velocity_mps, equal_nan=True)
    np.testing.assert_allclose(got.range_m, want.range_m, rtol=1e-12)


def test_a_replay_gives_the_same_bytes_on_any_worker_count_and_twice_in_a_process(capture, monkeypatch):
    path, _ = capture
    as_a_fresh_process(monkeypatch)
    runs = {"this thread (workers=0), first in the process": _tasks(map, path),
            "this thread, again": _tasks(map, path)}
    spawn = get_context("spawn")         # fresh interpreters: kernels not loaded, nothing counted
    for workers in (1, 2):
        with ProcessPoolExecutor(workers, mp_context=spawn) as ex:
            runs[f"{workers} fresh worker process(es)"] = _tasks(ex.map, path)
    runs["the DSP pool's workers (lidard.dsp_pool: kernels loaded at start)"] = _tasks(replay.local_map, path)
    ref_pts, ref_res = runs["this thread (workers=0), first in the process"]
    assert len(ref_pts) >= 40
    for name, (pts, res) in runs.items():
        assert pts.tobytes() == ref_pts.tobytes(), name
        np.testing.assert_array_equal(res, ref_res, err_msg=name)     # float64, NaN where no return


def test_the_public_replay_and_its_metadata_do_not_depend_on_the_map(capture, monkeypatch):
    path, _ = capture
    as_a_fresh_process(monkeypatch)
    first = reprocess(path, map_fn=map)
    pooled = reprocess(path)                       # local_map: the DSP pool (threads on one core)
    again = reprocess(path, map_fn=map)
    for other in (pooled, again):
        assert other.points.tobytes() == first.points.tobytes()
        assert other.meta == first.meta
    assert first.meta["tasks"] == 8 and first.meta["chunks"] == 48    # MIN_TASKS of 6 one-pixel chunks
