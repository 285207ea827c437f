"""Reprocessing a raw capture: the scan's DSP path gives the same points; overrides give their DSP's points."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from lidard.raw import (RawCaptureError, ReprocessSettings, chunk_count, frame_points, reprocess,
                        reprocess_chunk)


def _direct(syn, dsp, *, mzi=False):
    """What the scan loop computes for all pixels in one batch (FrameDsp + frame_points)."""
    kw = dict(mzi=syn.channel("mzi"), mzi_delay_s=10e-9, mzi_lsb_v=2.0 / 2**16) if mzi else {}
    res = dsp.process(syn.channel("beat"), 2.0 / 2**16, **kw)
    clipped = syn.overrange.reshape(len(syn.pixels), -1).any(axis=1)
    return frame_points(res, syn.pixels, syn.t_s, syn.directions, clipped,
                        dsp.measurement_delay_s(syn.channel("beat").shape[1]))


def test_original_settings_reproduce_the_direct_points_exactly(capture):
    out = reprocess(capture.path)
    ref = _direct(capture, capture.dsp)
    assert len(ref) >= 38
    assert out.points.dtype == ref.dtype and np.array_equal(out.points, ref)
    assert out.meta["chunks"] == 3 and out.meta["pixels"] == 40 and out.meta["raw_complete"]
    assert out.meta["dsp"]["estimator"] == capture.dsp.estimator and out.meta["overrides"] == {}


def test_points_sit_at_the_synthesised_ranges(capture):
    # physics, not a stored output: a tone at 2 gamma R / c is ranged to R (eq. 2-2) within a tenth of a bin
    pts = reprocess(capture.path).points
    first = pts[pts["return_index"] == 0]
    idx = first["row"].astype(int) * 8 + first["col"].astype(int)
    bin_m = capture.dsp.range_resolution_m
    assert np.max(np.abs(first["range"] - capture.range_true_m[idx])) < 0.1 * bin_m
    assert np.allclose(first["z"], capture.directions[idx, 2] * first["range"], rtol=1e-6)
    assert np.all(first["valid"][idx == 1] == 0)           # the clipped pixel is never a good point
    assert first["valid"][idx != 1].mean() > 0.9


@pytest.mark.parametrize("estimator", ["jacobsen", "argmax"])
def test_another_estimator_gives_that_estimators_points(capture, estimator):
    out = reprocess(capture.path, ReprocessSettings(estimator=estimator))
    ref = _direct(capture, dataclasses.replace(capture.dsp, estimator=estimator))
    assert np.array_equal(out.points, ref)
    assert not np.array_equal(out.points["range"], reprocess(capture.path).points["range"])
    assert out.meta["dsp"]["estimator"] == estimator and out.meta["overrides"] == {"estimator": estimator}


def test_window_and_pfa_overrides_reach_the_dsp(capture):
    out = reprocess(capture.path, ReprocessSettings(window="blackmanharris", pfa=1e-3))
    ref = _direct(capture, dataclasses.replace(capture.dsp, window="blackmanharris", pfa=1e-3))
    assert np.array_equal(out.points, ref)
    assert out.meta["dsp"]["window"] == "blackmanharris" and out.meta["dsp"]["pfa"] == 1e-3


def test_phase_noise_capture_replays_through_the_compensated_path(capture_mzi):
    on = reprocess(capture_mzi.path)
    assert len(on.points) >= 11                            # 12 pixels, one return each (one clipped)
    assert on.meta["dsp"]["phase_noise_compensation"] is True
    assert np.array_equal(on.points, _direct(capture_mzi, capture_mzi.dsp, mzi=True))
    off = reprocess(capture_mzi.path, ReprocessSettings(phase_noise=False))
    assert off.meta["dsp"]["phase_noise_compensation"] is False
    assert np.array_equal(off.points, _direct(capture_mzi, capture_mzi.dsp))


def test_phase_noise_on_needs_a_recorded_monitor(capture):
    with pytest.raises(RawCaptureError, match="no monitor 'mzi' channel"):
        reprocess(capture.path, ReprocessSettings(phase_noise=True))


@pytest.mark.parametrize("kw, match", [
    (dict(estimator="fft"), "estimator='fft' is not one of"),
    (dict(window="hamming"), "window='hamming' is not one of"),
    (dict(pfa=0.5), "pfa=0.5 must lie"),
    (dict(pfa=True), "pfa=True must lie"),
    (dict(phase_noise="on"), "phase_noise='on' must be true or false"),
])
def test_bad_overrides_are_named(kw, match):
    with pytest.raises(RawCaptureError, match=match):
        ReprocessSettings(**kw)


def test_one_chunk_is_one_picklable_task(capture):
    s = ReprocessSettings(estimator="jacobsen")
    task = pickle.loads(pickle.dumps((reprocess_chunk, str(capture.path), 1, s)))
    fn, path, idx, settings = task
    whole = reprocess(capture.path, s).points
    parts = [fn(path, i, settings) for i in range(chunk_count(path))]
    assert np.array_equal(np.concatenate(parts), whole)
    assert set(parts[1]["row"]) <= {2, 3}                  # chunk 1 = pixels 16..31 = rows 2 and 3


def test_a_crashed_capture_reprocesses_its_committed_prefix(make_capture):
    syn = make_capture("unclosed.zarr", close=False)     # 40 pixels appended, 2 chunks of 16 committed
    out = reprocess(syn.path)
    assert out.meta["raw_complete"] is False and out.meta["pixels"] == 32
    ref = _direct(syn, syn.dsp)
    assert np.array_equal(out.points, ref[(ref["row"].astype(int) * 8 + ref["col"]) < 32])


def test_a_recorded_quadrature_monitor_is_replayed_with_it(make_capture):
    # the quadrature reconstruction wants a whole number of samples per monitor delay: 100 ns at 10 MS/s
    syn = make_capture("quad.zarr", n_pix=6, chunk_pixels=4, with_mzi=True, with_mzi_q=True, batch=3,
                       mzi_delay_s=100e-9)
    assert syn.channels == ("beat", "mzi", "mzi_q")
    out = reprocess(syn.path)
    lsb = 2.0 / 2**16
    res = syn.dsp.process(syn.channel("beat"), lsb, mzi=syn.channel("mzi"), mzi_q=syn.channel("mzi_q"),
                          mzi_delay_s=100e-9, mzi_lsb_v=lsb)
    ref = frame_points(res, syn.pixels, syn.t_s, syn.directions, syn.overrange.reshape(6, -1).any(axis=1),
                       syn.dsp.measurement_delay_s(syn.channel("beat").shape[1]))
    assert len(ref) >= 5 and np.array_equal(out.points, ref)
    # without the quadrature channel this monitor (beat above Nyquist) could not be used at all
    from lidard.dsp.spectrum.window import DspInputError
    with pytest.raises(DspInputError, match="above Nyquist"):
        syn.dsp.process(syn.channel("beat"), lsb, mzi=syn.channel("mzi"), mzi_delay_s=100e-9, mzi_lsb_v=lsb)


def test_frame_points_move_each_range_back_to_its_t():
    # R(t) = R - v delay: a receding return measured later was nearer at t; x, y, z follow the range
    from lidard.dsp.frame import FrameDsp, FrameResult
    ones = np.ones((2, 1))
    res = FrameResult(present=ones.astype(bool), valid=ones.astype(bool), range_m=np.array([[1.0], [2.0]]),
                      velocity_mps=np.array([[4.0], [-2.0]]), snr_db=ones, intensity_v=ones)
    dsp = FrameDsp(ramp_samples=3200, fs_hz=40e6, chirp_rate_hz_per_s=1.075e14, wavelength_m=1.55e-6,
                   max_range_m=2.0, cw_samples=3120)
    delay = dsp.measurement_delay_s(10)
    assert delay == pytest.approx(80e-6 + 4.5 * 238e-6)      # ramp time + (averages - 1) / 2 periods
    pts = frame_points(res, np.array([[0, 0], [0, 1]]), np.zeros(2), np.array([[0, 0, 1.0], [0, 0, 1.0]]),
                       delay_s=delay)
    assert pts["range"].tolist() == pytest.approx([1.0 - 4.0 * delay, 2.0 + 2.0 * delay])
    assert pts["z"].tolist() == pytest.approx(pts["range"].tolist())


def test_reprocessing_leaves_no_dsp_buffers_held_by_the_thread(capture):
    """The frame DSP writes its spectra into per-thread scratch buffers (lidard.dsp.spectrum.scratch); a
    reprocessing run in this thread hands them back when it ends, as a scan does."""
    from lidard.dsp.spectrum import scratch as scratch_mod

    reprocess(capture.path)
    assert getattr(scratch_mod._LOCAL, "bufs", None) is None
    scratch_mod.scratch("t.held", (8,), np.float64)
    assert scratch_mod._LOCAL.bufs        # the check above can fail: buffers do stay between uses
    scratch_mod.release()


@pytest.mark.parametrize("task_bytes", [1, 20_000, 1 << 30])
def test_scan_sized_tasks_of_several_chunks_give_the_same_points(capture, monkeypatch, task_bytes):
    # one chunk a task, a few chunks a task, the whole capture in one task: the DSP treats pixels on
    # their own, so the cloud is the direct one whatever the tasks; local threads and a plain map agree
    from lidard.raw import replay
    monkeypatch.setattr(replay, "TASK_BYTES", task_bytes)
    monkeypatch.setattr(replay, "MIN_TASKS", 1)
    ref = _direct(capture, capture.dsp)
    n_tasks = replay.task_count(capture.path)
    assert (n_tasks == 3) if task_bytes == 1 else (n_tasks == 1) if task_bytes == 1 << 30 else (1 <= n_tasks <= 3)
    threaded = reprocess(capture.path)
    serial = reprocess(capture.path, map_fn=map)
    assert threaded.meta["tasks"] == n_tasks and threaded.meta["chunks"] == 3
    assert np.array_equal(threaded.points, ref) and np.array_equal(serial.points, ref)
    with pytest.raises(RawCaptureError, match="out of range"):
        replay.reprocess_task(capture.path, n_tasks)


def test_a_capture_is_cut_into_at_least_min_tasks_when_it_has_the_chunks(make_capture, monkeypatch):
    # 40 pixels in chunks of 2: 20 chunks; tasks of every chunk (TASK_BYTES huge) would leave one task
    # and one busy core, so the cut stops at MIN_TASKS tasks; a capture of fewer chunks gets one a chunk
    from lidard.raw import replay
    cap = make_capture("many.zarr", chunk_pixels=2)
    monkeypatch.setattr(replay, "TASK_BYTES", 1 << 30)
    monkeypatch.setattr(replay, "MIN_TASKS", 8)
    assert replay.task_count(cap.path) == 10               # 2 chunks a task: 20 // 8
    monkeypatch.setattr(replay, "MIN_TASKS", 30)
    assert replay.task_count(cap.path) == 20               # fewer chunks than MIN_TASKS: one a task
    monkeypatch.setattr(replay, "MIN_TASKS", 1)
    assert replay.task_count(cap.path) == 1
    monkeypatch.setattr(replay, "MIN_TASKS", 8)
    rep = reprocess(cap.path, map_fn=map)
    assert rep.meta["tasks"] == 10 and np.array_equal(rep.points, _direct(cap, cap.dsp))
