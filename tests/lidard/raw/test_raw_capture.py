"""Raw captures in Zarr: round trip, chunk layout, commit state, refusals, crash leaves a prefix."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import zarr

from lidard.raw import RawCapture, RawCaptureError, RawWriter, capture_size_bytes, remove_capture


def test_round_trip_every_array_and_the_reprocessing_attributes(capture):
    cap = RawCapture(capture.path)
    assert cap.complete and cap.n_pixels == 40 and cap.averages == 2
    assert cap.n_chunks == 3                                   # 16 + 16 + 8 pixels
    got = np.concatenate([cap.chunk(i).segments for i in range(cap.n_chunks)])
    assert got.dtype == np.int16 and np.array_equal(got, capture.segments)
    chunks = [cap.chunk(i) for i in range(3)]
    assert np.array_equal(np.concatenate([c.pixels for c in chunks]), capture.pixels)
    assert np.array_equal(np.concatenate([c.directions for c in chunks]), capture.directions)
    assert np.array_equal(np.concatenate([c.t_s for c in chunks]), capture.t_s)
    assert np.array_equal(np.concatenate([c.overrange for c in chunks]), capture.overrange)
    assert chunks[0].clipped[1] and chunks[0].clipped.sum() == 1
    a = cap.attrs
    assert a["channels"] == ["beat"] and a["calibration_id"] == "cal-test"
    assert a["dsp"]["ramp_samples"] == 512 and a["adc"]["lsb_v"] == 2.0 / 2**16
    assert a["software"]["zarr"] == zarr.__version__ and a["scan_partial"] is False


def test_one_chunk_file_per_block_of_whole_records(capture):
    # the segments array's chunk i holds the whole records (all channels, all samples) of chunk i's pixels
    g = zarr.open_group(str(capture.path), mode="r")
    seg = g["segments"]
    assert seg.chunks == (16 * 2, 1, 1024)
    files = sorted(str(p.relative_to(capture.path / "segments")) for p in capture.path.glob("segments/c/**/*")
                   if p.is_file())
    assert files == ["c/0/0/0", "c/1/0/0", "c/2/0/0"]


def test_close_trims_a_cancelled_scan_to_the_pixels_written(make_capture, tmp_path):
    w = RawWriter.create(tmp_path / "short.zarr", pixels=np.zeros((10, 2), np.int64),
                         directions=np.tile([0.0, 0.0, 1.0], (10, 1)), averages=1, channels=("beat",),
                         record_length=8, chunk_pixels=4, attrs={"adc": {"lsb_v": 1.0}, "dsp": {}})
    w.append(np.ones((6, 1, 8), np.int16), np.arange(6), np.zeros(6), np.arange(6.0))
    w.close(stop_reason="cancelled")
    cap = RawCapture(tmp_path / "short.zarr")
    assert cap.complete and cap.n_pixels == 6 and cap.n_chunks == 2
    assert cap.attrs["scan_partial"] is True and cap.attrs["stop_reason"] == "cancelled"
    g = zarr.open_group(str(tmp_path / "short.zarr"), mode="r")
    assert g["segments"].shape == (6, 1, 8) and g["pixels"].shape == (6, 2)
    assert cap.chunk(1).segments.shape == (2, 1, 8)


@pytest.mark.parametrize("bad, match", [
    (dict(segments=np.zeros((2, 1, 8), np.float32)), "int16"),
    (dict(segments=np.zeros((3, 1, 8), np.int16)), "int16"),
    (dict(trigger_time_ns=np.zeros(1)), "one entry per segment"),
])
def test_append_refuses_records_that_do_not_fit(tmp_path, bad, match):
    w = RawWriter.create(tmp_path / "r.zarr", pixels=np.zeros((4, 2), np.int64),
                         directions=np.tile([0.0, 0.0, 1.0], (4, 1)), averages=1, channels=("beat",),
                         record_length=8, chunk_pixels=2, attrs={"adc": {"lsb_v": 1.0}, "dsp": {}})
    args = dict(segments=np.zeros((2, 1, 8), np.int16), trigger_time_ns=np.zeros(2), overrange=np.zeros(2),
                t_s=np.zeros(2))
    args.update(bad)
    with pytest.raises(RawCaptureError, match=match):
        w.append(**args)


def test_more_pixels_than_planned_and_overwrite_are_refused(capture, tmp_path):
    with pytest.raises(RawCaptureError, match="already exists"):
        RawWriter.create(capture.path, pixels=np.zeros((1, 2)), directions=np.zeros((1, 3)), averages=1,
                         channels=("beat",), record_length=8, chunk_pixels=1, attrs={"adc": {}, "dsp": {}})
    w = RawWriter.create(tmp_path / "r.zarr", pixels=np.zeros((1, 2)), directions=np.zeros((1, 3)), averages=1,
                         channels=("beat",), record_length=8, chunk_pixels=4, attrs={"adc": {}, "dsp": {}})
    with pytest.raises(RawCaptureError, match="more pixels than the 1 planned"):
        w.append(np.zeros((2, 1, 8), np.int16), np.zeros(2), np.zeros(2), np.zeros(2))
    with pytest.raises(RawCaptureError, match="lack 'dsp'"):
        RawWriter.create(tmp_path / "s.zarr", pixels=np.zeros((1, 2)), directions=np.zeros((1, 3)), averages=1,
                         channels=("beat",), record_length=8, chunk_pixels=1, attrs={"adc": {}})


def test_reader_names_a_missing_capture_chunk_and_pixel(capture, tmp_path):
    with pytest.raises(RawCaptureError, match="not found"):
        RawCapture(tmp_path / "nope.zarr")
    cap = RawCapture(capture.path)
    with pytest.raises(RawCaptureError, match="chunk 3 out of range"):
        cap.chunk(3)
    with pytest.raises(RawCaptureError, match=r"pixel \(99, 0\) was not recorded"):
        cap.pixel_index(99, 0)


def test_size_and_removal(capture):
    size = capture_size_bytes(capture.path)
    assert size > 0 and size == sum(f.stat().st_size for f in capture.path.rglob("*") if f.is_file())
    assert remove_capture(capture.path) and not capture.path.exists()
    assert capture_size_bytes(capture.path) == 0 and remove_capture(capture.path) is False


_CHILD = textwrap.dedent("""
    import sys, numpy as np
    from lidard.raw import RawWriter
    w = RawWriter.create(sys.argv[1], pixels=np.zeros((50, 2), np.int64), directions=np.tile([0., 0., 1.], (50, 1)),
                         averages=1, channels=("beat",), record_length=64, chunk_pixels=10,
                         attrs={"adc": {"lsb_v": 1.0}, "dsp": {}})
    for k in range(3):   # 30 pixels: 3 committed chunks; 5 more pixels wait in memory
        w.append(np.full((10, 1, 64), k + 1, np.int16), np.arange(10), np.zeros(10), np.arange(10.0))
    w.append(np.full((5, 1, 64), 9, np.int16), np.arange(5), np.zeros(5), np.arange(5.0))
    print("written", flush=True)
    sys.stdin.read()      # wait here until killed
""")


def test_a_process_killed_mid_scan_leaves_a_readable_prefix_marked_partial(tmp_path):
    path = tmp_path / "crash.zarr"
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(path)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "written"
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    cap = RawCapture(path)
    assert cap.complete is False and cap.n_chunks == 3 and cap.n_pixels == 30
    for k in range(3):
        assert np.all(cap.chunk(k).segments == k + 1)
    meta = json.loads((path / "zarr.json").read_text())
    assert meta["attributes"]["complete"] is False
    # zarr's LocalStore writes to a temporary name and renames: no torn or temporary files remain
    assert not list(path.rglob("*.partial"))


def test_a_chunk_count_ahead_of_the_pixels_written_is_not_a_chunk(capture):
    # kill -9 between a chunk's count and its pixels' count: the reader answers only the chunks that
    # hold written pixels (an empty one made the reprocessing of a killed scan fail)
    g = zarr.open_group(zarr.storage.LocalStore(capture.path), mode="r+")
    g.attrs.update({"chunks_complete": 4, "pixels_written": 32})
    cap = RawCapture(capture.path)
    assert cap.n_pixels == 32 and cap.n_chunks == 2
    assert all(len(cap.chunk(i).t_s) == 16 for i in range(cap.n_chunks))
