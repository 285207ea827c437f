"""The scan loop's recorder: records as read (any channel order), headers kept, a failing disk never stops a scan."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidard.dsp.frame import FrameDsp
from lidard.raw import RawCapture
from lidard.raw.record import RecordLayout, ReplayRecipe, ScanDescription, ScanRecorder


@dataclass
class Header:
    trigger_time_ns: int
    overrange: int


def _start(path, **kw):
    # the whole 8-sample ramp used: the smallest range FFT a FrameDsp builds (n >= 8)
    dsp = FrameDsp(ramp_samples=8, use_fraction=1.0, fs_hz=1e6, chirp_rate_hz_per_s=1e14, wavelength_m=1.55e-6,
                   max_range_m=2.0)
    layout = RecordLayout(pixels=np.array([[0, 0], [0, 1], [1, 0]]), directions=np.tile([0.0, 0.0, 1.0], (3, 1)),
                          averages=2, channels=("mzi", "beat"), record_length=16)
    recipe = ReplayRecipe(dsp=dsp, lsb_v=3e-5, phase_noise=True, mzi_delay_s=2e-7)
    about = ScanDescription(adc={"sample_rate_hz": 1e6, "bits": 16}, chirp={"excursion_hz": 8.6e9},
                            calibration_id="c1", scan={"id": "S1"})
    args = dict(drive_v=np.linspace(-1, 1, 5), chunk_bytes=2 * 16 * 2 * 2)
    args.update(kw)
    return ScanRecorder.start(path, layout, recipe, about, **args)


def test_records_arrive_in_the_recorded_channel_order_with_their_headers(tmp_path):
    rec = _start(tmp_path / "r.zarr")
    seg = np.arange(6 * 2 * 16, dtype=np.int16).reshape(6, 2, 16)        # digitizer order: beat, mzi
    hdr = [Header(1000 * i, int(i == 4)) for i in range(6)]
    rec.add(seg[:4], hdr[:4], np.array([0.0, 1e-4]), ("beat", "mzi"))
    rec.add(seg[4:], hdr[4:], np.array([2e-4]), ("beat", "mzi"))
    rec.close(pixels_scanned=3)
    cap = RawCapture(tmp_path / "r.zarr")
    assert cap.channels == ["mzi", "beat"] and cap.n_chunks == 3 and cap.complete
    got = np.concatenate([cap.chunk(i).segments for i in range(3)])
    assert np.array_equal(got[:, 0], seg[:, 1]) and np.array_equal(got[:, 1], seg[:, 0])
    assert np.array_equal(np.concatenate([cap.chunk(i).trigger_time_ns for i in range(3)]), 1000 * np.arange(6))
    assert cap.chunk(2).clipped.tolist() == [True]
    a = cap.attrs
    assert a["phase_noise"] == {"on": True, "mzi_delay_s": 2e-7} and a["calibration_id"] == "c1"
    assert a["adc"]["lsb_v"] == 3e-5 and a["dsp"]["ramp_samples"] == 8 and a["scan"] == {"id": "S1"}
    assert np.array_equal(cap.drive_v(), np.linspace(-1, 1, 5)) and a["pixels_scanned"] == 3


def test_a_recording_failure_is_reported_not_raised(tmp_path):
    rec = _start(tmp_path / "r.zarr")
    rec.add(np.zeros((2, 2, 16), np.int16), [Header(0, 0)] * 2, np.zeros(1), ("beat", "mzi"))
    rec.add(np.zeros((2, 2, 15), np.int16), [Header(0, 0)] * 2, np.zeros(1), ("beat", "mzi"))   # wrong length
    assert rec.error is not None and "int16" in rec.error
    rec.add(np.zeros((2, 2, 16), np.int16), [Header(0, 0)] * 2, np.zeros(1), ("beat", "mzi"))   # ignored now
    rec.close()
    cap = RawCapture(tmp_path / "r.zarr")
    assert cap.n_chunks == 1 and cap.complete is False                     # the prefix, marked partial


def test_pixels_recorded_counts_what_the_writer_accepted(tmp_path):
    rec = _start(tmp_path / "r.zarr")
    rec.add(np.zeros((4, 2, 16), np.int16), [Header(0, 0)] * 4, np.zeros(2), ("beat", "mzi"))
    assert rec.pixels_recorded == 2
    rec.add(np.zeros((2, 2, 16), np.int16), [Header(0, 0)] * 2, np.zeros(3), ("beat", "mzi"))  # refused
    assert rec.pixels_recorded == 2 and rec.error is not None
