"""Small synthetic raw captures for tests: beat tones at known ranges, written as the scan loop writes them.

``from tests.helpers.raw_capture import write_capture`` (pyproject sets pytest's pythonpath).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidard.dsp.frame import FrameDsp
from lidard.dsp.spectrum.rangefft import C_M_PER_S
from lidard.instrument import ScanResult
from lidard.raw import RawWriter, frame_dsp_attrs, reprocess
from lidard.instrument.plan import plan
from tests.helpers.fakes import FakeInstrument

FS_HZ = 10e6
RAMP_SAMPLES = 512
GAMMA_HZ_PER_S = 1.075e14      # the simulated bench's chirp: 8.6 GHz in 80 us
MZI_DELAY_S = 10e-9
LSB_V = 2.0 / 2**16


@dataclass
class Synthetic:
    path: Path
    dsp: FrameDsp
    segments: np.ndarray        # (n_pix * avg, n_ch, record) int16, as written
    channels: tuple[str, ...]
    averages: int
    pixels: np.ndarray
    directions: np.ndarray
    t_s: np.ndarray
    overrange: np.ndarray
    range_true_m: np.ndarray    # (n_pix,)

    def channel(self, name: str) -> np.ndarray:
        s = self.segments[:, self.channels.index(name), :]
        return s.reshape(len(self.pixels), self.averages, -1)


def synth_segments(rng, ranges_m, averages, with_mzi, with_mzi_q=False, mzi_delay_s=MZI_DELAY_S):
    """Up and down ramp of a static target: the same beat 2 gamma R / c on both (eq. 2-2)."""
    n = len(ranges_m)
    t = np.arange(2 * RAMP_SAMPLES) / FS_HZ
    f = 2 * GAMMA_HZ_PER_S * np.asarray(ranges_m) / C_M_PER_S
    ph = rng.uniform(0, 2 * np.pi, (n, averages, 1))
    beat = 3000 * np.cos(2 * np.pi * f[:, None, None] * t + ph) + rng.normal(0, 30, (n, averages, t.size))
    chans = [beat]
    if with_mzi:
        ph2 = rng.uniform(0, 2 * np.pi, (n, averages, 1))
        arg = 2 * np.pi * GAMMA_HZ_PER_S * mzi_delay_s * t + ph2
        chans.append(3000 * np.cos(arg) + rng.normal(0, 30, (n, averages, t.size)))
        if with_mzi_q:     # the monitor's quadrature output: the same fringe 90 degrees on
            chans.append(3000 * np.sin(arg) + rng.normal(0, 30, (n, averages, t.size)))
    seg = np.stack(chans, axis=2)                    # (n, avg, n_ch, record)
    return np.rint(seg).astype(np.int16).reshape(n * averages, len(chans), -1)


def write_capture(path, *, n_pix=40, averages=2, chunk_pixels=16, with_mzi=False, batch=7, seed=0,
                  close=True, pixels=None, directions=None, with_mzi_q=False,
                  mzi_delay_s=MZI_DELAY_S) -> Synthetic:
    """A capture of ``n_pix`` pixels (default layout: 8 per row) with one target each at 1..3.5 m."""
    rng = np.random.default_rng(seed)
    if pixels is not None:
        n_pix = len(pixels)
    ranges = rng.uniform(1.0, 3.5, n_pix)
    if pixels is None:
        pixels = np.stack([np.arange(n_pix) // 8, np.arange(n_pix) % 8], axis=1)
    pixels = np.asarray(pixels, dtype=np.int64)
    v = np.stack([rng.normal(0, 0.1, n_pix), rng.normal(0, 0.1, n_pix), np.ones(n_pix)], axis=1)
    directions = v / np.linalg.norm(v, axis=1, keepdims=True) if directions is None else directions
    seg = synth_segments(rng, ranges, averages, with_mzi, with_mzi_q, mzi_delay_s)
    overrange = np.zeros(n_pix * averages, np.uint8)
    overrange[3] = 1                                 # pixel 1 has a clipped segment
    t_s = np.arange(n_pix) * 2 * averages * RAMP_SAMPLES / FS_HZ
    trig = (t_s[:, None] * 1e9 + np.arange(averages) * 2 * RAMP_SAMPLES / FS_HZ * 1e9).astype(np.int64).ravel()
    dsp = FrameDsp(ramp_samples=RAMP_SAMPLES, fs_hz=FS_HZ, chirp_rate_hz_per_s=GAMMA_HZ_PER_S,
                   wavelength_m=1.55e-6, max_range_m=4.0, max_speed_mps=0.4, window="hann", pfa=1e-6)
    channels = ("beat", "mzi", "mzi_q")[:1 + with_mzi + (with_mzi and with_mzi_q)]
    w = RawWriter.create(path, pixels=pixels, directions=directions, averages=averages, channels=channels,
                         record_length=2 * RAMP_SAMPLES, chunk_pixels=chunk_pixels,
                         attrs={"adc": {"lsb_v": LSB_V, "sample_rate_hz": FS_HZ}, "dsp": frame_dsp_attrs(dsp),
                                "phase_noise": {"on": with_mzi, "mzi_delay_s": mzi_delay_s},
                                "calibration_id": "cal-test"})
    for p0 in range(0, n_pix, batch):              # reads of uneven size, as the scan loop's
        p1 = min(p0 + batch, n_pix)
        s0, s1 = p0 * averages, p1 * averages
        w.append(seg[s0:s1], trig[s0:s1], overrange[s0:s1], t_s[p0:p1])
    if close:
        w.close(stop_reason=None)
    return Synthetic(path=Path(path), dsp=dsp, segments=seg, channels=channels, averages=averages,
                     pixels=pixels, directions=directions, t_s=t_s, overrange=overrange, range_true_m=ranges)


class RecordingFake(FakeInstrument):
    """Writes a synthetic capture for the planned pixels when asked (raw_path), as the scan loop does;
    its points are the DSP's points of that capture."""

    def run_scan(self, request, progress, cancel, calibration=None, raw_path=None):
        self.requests.append(request)
        self.raw_paths = getattr(self, "raw_paths", []) + [raw_path]
        pixels = plan(request, self.optics)
        if raw_path is None:
            return super().run_scan(request, progress, cancel, calibration)
        write_capture(raw_path, pixels=pixels, directions=self.optics.directions(pixels[:, 0], pixels[:, 1]),
                      chunk_pixels=8)
        # on this thread: a fake's scan must not wait for the DSP worker processes' first start (their
        # forkserver loads the compiled kernels: minutes under a heavy load on a fresh clone's cold cache)
        pts = reprocess(raw_path, map_fn=map).points
        return ScanResult(points=pts, meta={"fake": True}, pixels_scanned=len(pixels), pixels_planned=len(pixels),
                          hardware_time_s=1e-3 * len(pixels))
