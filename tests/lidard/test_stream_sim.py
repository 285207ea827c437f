"""Streams on the embedded simulated bench: one bring-up for all frames, frames to MCAP, a stop keeps
the frames (and the partial one), the interlock stops a stream as it stops a scan."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument
from lidard.instrument.stream import FRAME_READ_S, FRAME_TAIL_S, FramePlan, read_size
from lidard.jobs.stream_job import FrameSink
from lidard.outputs.mcap import read_mcap
from lidard.instrument.plan import plan

pytestmark = pytest.mark.slow

REQ = ScanRequest(pattern="roi", rows=(48, 68), cols=(48, 68), max_range_m=2.0)   # 300 bonded pixels


@pytest.fixture(scope="module")
def inst():
    cfg = load_config("config/sim.toml")
    i = open_instrument(cfg, scene_path="config/scenes/cal_letters.toml", bench="embedded")
    yield i
    i.close()


def _fixed(inst):
    px = plan(REQ, inst.optics)
    return px, (lambda k, h: FramePlan(px, {"pattern": "roi"}))


def test_frames_to_mcap_with_one_bring_up(inst, tmp_path, monkeypatch):
    px, planner = _fixed(inst)
    ups, configures = [], []
    real = inst.safety.bring_up
    monkeypatch.setattr(inst.safety, "bring_up", lambda **kw: (ups.append(1), real(**kw))[1])
    real_conf = inst.digitizer.configure
    monkeypatch.setattr(inst.digitizer, "configure", lambda **kw: (configures.append(kw), real_conf(**kw))[1])
    sink = FrameSink(str(tmp_path / "s.mcap"), "ply", {})
    frames = []
    res = inst.run_stream(REQ, planner, lambda f: (frames.append(f), sink.add(f)), threading.Event(), frames=3)
    sink.close()
    assert res.frames == 3 and res.stop_reason is None and len(ups) == 1
    # one digitizer acquisition for all frames: configured and armed once, its segments numbered on
    assert len(configures) == 1 and res.meta["digitizer_arms"] == 1
    assert configures[0]["segments"] >= 3 * len(px)
    # ... and each frame's segments are its own pixels' (the static scene: the same ranges frame to frame)
    first = lambda p: p[p["return_index"] == 0]    # noqa: E731  (unlinearized: few returns pass as valid)
    ref = first(frames[0].points)
    key = lambda p: p["row"].astype(np.int64) * 1000 + p["col"]   # noqa: E731
    for f in frames[1:]:
        v = first(f.points)
        common, i0, i1 = np.intersect1d(key(ref), key(v), return_indices=True)
        assert len(common) >= 0.9 * len(ref) > 100
        assert np.median(np.abs(ref["range"][i0] - v["range"][i1])) < 0.005
    pts, statuses = read_mcap(tmp_path / "s.mcap")
    assert [s["frame"] for s in statuses] == [0, 1, 2]
    assert sorted(set(pts["frame"].tolist())) == [0, 1, 2]
    for f, s in zip(frames, statuses):
        assert s["pixels_scanned"] == len(px) and s["points"] == len(f.points)
        # t counts from the stream's first trigger: a frame's points lie inside its own trigger span
        assert f.points["t"].min() >= f.start_s - 1e-9
        assert f.points["t"].max() <= f.start_s + f.hardware_time_s
    starts = [f.start_s for f in frames]
    # back to back: the next frame starts after this one's triggers (plus its set-up gap)
    for a, b in zip(frames, frames[1:]):
        assert b.start_s == pytest.approx(a.start_s + a.hardware_time_s + b.setup_s, abs=1e-6)
    assert starts[0] == 0.0


def test_a_frame_is_read_in_steps_then_halving_to_its_last_pixels():
    sizes, left = [], 396
    while left:
        sizes.append(read_size(left, 20, 4))
        left -= sizes[-1]
    assert sizes == [20] * 18 + [18, 9, 5, 4]          # steps, then halving to the tail read
    assert read_size(3, 20, 4) == 3 and read_size(7, 20, 4) == 3 and read_size(60, 20, 4) == 20


def test_stop_keeps_finished_frames_and_the_partial_one(inst, monkeypatch):
    px, planner = _fixed(inst)
    cancel = threading.Event()
    frames = []
    reads = []
    real = inst.acquisition.read

    pixel_s = inst.cfg.chirp.period_s + inst.cfg.scan.settle_s
    step, tail = int(FRAME_READ_S / pixel_s), int(FRAME_TAIL_S / pixel_s)
    per_frame, left = 0, len(px)                       # 5 ms reads, halving to the last 1 ms
    while left:
        left -= read_size(left, step, tail)
        per_frame += 1

    def read(acq, first, count):   # stop inside frame 1, after its first read (frame 0 takes per_frame)
        reads.append(count)
        if len(reads) == per_frame + 1:
            cancel.set()
        return real(acq, first, count)

    monkeypatch.setattr(inst.acquisition, "read", read)
    res = inst.run_stream(REQ, planner, frames.append, cancel, frames=5)
    assert res.cancelled and res.frames == 2
    assert not frames[0].partial and frames[0].pixels_scanned == len(px)
    assert frames[1].partial and 0 < frames[1].pixels_scanned < len(px)
    assert set(frames[1].points["frame"].tolist()) == {1}


def test_interlock_stops_the_stream_and_keeps_frames(inst):
    px, planner = _fixed(inst)
    frames = []
    inst.inject_fault("interlock_open", after_segments=len(px) + 100)   # inside frame 1
    try:
        res = inst.run_stream(REQ, planner, frames.append, threading.Event(), frames=4)
    finally:
        inst.clear_faults()
        inst.controller.clear_faults()       # the latched INTERLOCK_OPEN
    assert res.frames == 2 and "interlock" in (res.stop_reason or "")
    assert "safe_state" in res.meta
    assert not frames[0].partial and frames[1].partial
    assert frames[1].pixels_scanned < len(px)


SMALL = ScanRequest(pattern="roi", rows=(48, 56), cols=(48, 56), max_range_m=2.0)   # 48 bonded pixels


def _small(inst):
    px = plan(SMALL, inst.optics)
    return lambda k, h: FramePlan(px)


def test_health_check_repeats_after_its_hardware_time_budget(inst):
    """A 1 ms budget with 12 ms frames: the check runs before every frame after the first, on the real
    monitor MZI, and the stream goes on (outputs brought up again, drive reloaded)."""
    frames = []
    cal = inst.linearize()          # the plain drive fails the check (as it should): linearized first
    res = inst.run_stream(SMALL, _small(inst), frames.append, threading.Event(), cal, frames=3,
                          health_interval_s=0.001)
    assert res.frames == 3 and res.stop_reason is None
    assert len(res.health) == 2 and all("hardware time" in h["why"] for h in res.health)
    assert res.meta["digitizer_arms"] == 3        # the check used the digitizer: each frame set it up again
    assert all(not h["exceeded"] and h["residual_hz"] < h["threshold_hz"] for h in res.health)
    assert all(len(f.points) > 0 for f in frames)


def test_tec_step_triggers_the_check_and_a_failed_check_stops_the_stream(inst):
    from lidard.instrument.stream import StreamLoop
    tec = iter([25.0, 25.0, 25.0 + 2 * inst.cfg.scan.recalibrate_delta_c] + [30.0] * 10)
    calls = []

    class Off:                      # what LinearizationHealth answers for a drifted chirp
        residual_hz, threshold_hz, exceeded = 9e5, 2e5, True

        def reason(self):
            return "chirp error 900 kHz above 200 kHz"

    def health():
        calls.append(1)
        return Off()

    loop = StreamLoop(inst.scan_loop, health=health, tec=lambda: next(tec), tec_poll_s=0.0)
    from lidard.instrument.acquisition import plain_drive
    frames = []
    res = loop.run(SMALL, _small(inst), frames.append, threading.Event(),
                   plain_drive(inst.cfg, inst.laser.static_tuning_hz_per_v), frames=5)
    # TEC read at the start (25.0), before frame 1 (25.0: no check), before frame 2 (stepped: check)
    assert calls == [1] and res.frames == 2
    assert "TEC moved" in res.health[0]["why"] and "900 kHz" in res.stop_reason


def test_stream_job_hands_each_frame_to_the_live_listeners(inst, tmp_path):
    """Each finished frame reaches the point listeners (web viewer, Foxglove) as one complete cloud under
    its own id and the event listeners as a "frame" event carrying its sidecar; the files are written."""
    from lidard.jobs.events import EventHub
    from lidard.jobs.stream_job import StreamJob, StreamSpec, frame_id

    class Worker:                   # what StreamJob.run needs of the scan worker
        instrument, last_linearization, events, optics = inst, None, EventHub(), inst.optics
        asked_for: list = []

        def current_linearization(self, request=None):
            # the worker picks the range record for the stream's request (its phase-noise mode)
            self.asked_for.append(request)
            return None

    w = Worker()
    clouds, events = [], []
    w.events.add_point_listener(lambda sid, pts, final: clouds.append((sid, len(pts), final, set(pts["frame"]))))
    w.events.add_event_listener(events.append)
    job = StreamJob(StreamSpec(SMALL, frames=2, out=str(tmp_path / "frames")))
    job.run(w)
    assert job.state == "done" and len(job.frames) == 2
    assert w.asked_for == [job.spec.request]
    assert [c[0] for c in clouds] == [frame_id(job.id, 0), frame_id(job.id, 1)]
    assert all(c[2] and c[1] > 0 and c[3] == {k} for k, c in enumerate(clouds))
    assert [(e["event"], e["frame"], e["points"]) for e in events[:-1]] == [("frame", k, clouds[k][1]) for k in range(2)]
    assert events[-1] == {"event": "end", "id": job.id, "state": "done", "frames": 2, "stop_reason": None,
                          "error": None}
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == [
        "frame_00000.ply", "frame_00000.ply.json", "frame_00001.ply", "frame_00001.ply.json"]


@pytest.mark.parametrize("held", [True, False])
def test_scene_motion_refers_to_the_streams_first_trigger(held):
    """A box crossing at 0.1 m/s: with the bench's scene clock held (what run_stream does) the box
    points of the fifth frame are where the ground truth at their stream ``t`` puts the box; released
    (each frame a new scene t = 0), the box is seen back where it started and the truth disagrees."""
    from lidard.instrument.acquisition import drive_for_chirp
    from lidard.instrument.stream import StreamLoop
    cfg = load_config("config/sim.toml")
    i = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    bench = i._on_close.__self__
    try:
        cal = i.linearize()
        i.set_scene({"target": [
            {"kind": "box", "center": [-0.02, 0.0, 1.0], "size": [0.03, 0.03, 0.01], "reflectivity": 0.8,
             "velocity": [0.1, 0.0, 0.0]},
            {"kind": "plane", "point": [0.0, 0.0, 2.5], "normal": [0.0, 0.0, -1.0], "reflectivity": 0.9}]})
        req = ScanRequest(pattern="roi", rows=(60, 68), cols=(40, 88), max_range_m=3.0)
        px = plan(req, i.optics)
        hook = i._sim.hold_scene_clock if held else None
        loop = StreamLoop(i.scan_loop, scene_clock=hook)
        frames = []
        loop.run(req, lambda k, h: FramePlan(px), frames.append, threading.Event(),
                 drive_for_chirp(cfg, cal.drive_v), cal, frames=5)
        last = frames[-1].points
        near = last[(last["valid"] == 1) & (last["range"] < 2.0)]
        assert frames[-1].start_s > 0.2 and len(near) >= 10
        truth = bench.ground_truth(near["row"], near["col"], near["t"])
        on_box = float(np.mean(truth < 2.0))
        if held:
            assert on_box >= 0.9
        else:
            assert on_box <= 0.5
    finally:
        i.close()


def test_max_speed_sizes_the_streams_adc_band(inst):
    """A stream asking for 1.5 m/s samples a wider Doppler band than the configuration's 0.4 m/s."""
    import dataclasses
    rates = []
    for v in (None, 1.5):
        req = dataclasses.replace(SMALL, max_speed_mps=v)
        res = inst.run_stream(req, _small(inst), lambda f: None, threading.Event(), frames=1)
        rates.append(res.meta["adc"]["sample_rate_hz"])
    assert rates[1] > rates[0]


def test_a_frame_that_never_triggered_starts_where_the_last_one_ended():
    from lidard.instrument.stream import _State
    st = _State(t0_ns=1e9, end_ns=3.5e9)            # the stream's first trigger; the last frame's end
    assert st.start_s(2.0e9) == pytest.approx(1.0)    # a frame that triggered: its first trigger
    assert st.start_s(None) == pytest.approx(2.5)     # a stop during its set-up: no trigger
    assert _State().start_s(None) == 0.0              # the first frame, stopped before any trigger
