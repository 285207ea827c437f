"""The limit kernel of a frame scan: only its unavoidable work, in plain numpy (issue 18, item 1).

A frame scan of ``pixels`` x ``averages`` triggers, ``record_length`` samples on ``channels``
digitizer channels, cannot do less than

* synthesis: produce that many samples, a cosine at a beat frequency plus white noise, quantized
  to int16 (what the bench's synthesis must at least do for a static target, §2.1 eq. 2-3);
* transport: move those bytes once (one copy of the int16 records out of a byte buffer, what a
  bulk-transfer read must at least do);
* DSP: one windowed real FFT per ramp of the used length (the up and the down ramp of each
  trigger, ``n_used`` samples each), the powers of a pixel's triggers averaged, one argmax per
  pixel and ramp (the least a range estimate needs, §2.1);
* points: write the same number of points as a binary PLY (header + one ``tofile``).

Each stage is timed on wall and process CPU time; :func:`stage_ratios` divides a scan's stage
times by these. Processing is chunked (``chunk_samples`` per chunk) so the limit's memory stays
small, as a scan's does. numpy's FFT is single-threaded; BLAS is not used.

    python benchmarks/limit.py --pixels 12288 --averages 10 --record-length 800 --ramp-samples 400
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

import numpy as np

STAGES = ("synthesis", "transport", "dsp", "points")


class _Clock:
    """Wall and CPU seconds accumulated per stage."""

    def __init__(self):
        self.wall = dict.fromkeys(STAGES, 0.0)
        self.cpu = dict.fromkeys(STAGES, 0.0)

    def run(self, stage: str, fn, *a):
        t, c = time.perf_counter(), time.process_time()
        out = fn(*a)
        self.wall[stage] += time.perf_counter() - t
        self.cpu[stage] += time.process_time() - c
        return out


def _synth(rng, n_rec: int, record_length: int, channels: int, fs_hz: float) -> np.ndarray:
    """cos(2 pi f t + phi) + noise at 0.1 of full scale, as int16 codes: (n_rec, channels, L)."""
    t = np.arange(record_length, dtype=np.float32) / np.float32(fs_hz)
    f = rng.uniform(0.05, 0.4, (n_rec, channels, 1)).astype(np.float32) * np.float32(fs_hz)
    phase = (2 * np.pi * f) * t
    x = np.cos(phase, out=phase)
    x += rng.standard_normal(x.shape, dtype=np.float32) * np.float32(0.1)
    x *= np.float32(0.4 * 32767)
    return x.astype(np.int16)


def _dsp(codes: np.ndarray, averages: int, ramp_samples: int, n_used: int, window: np.ndarray) -> np.ndarray:
    """Windowed rfft of each ramp of channel 0, powers averaged per pixel, argmax: (n_pix, 2)."""
    n_pix = codes.shape[0] // averages
    off = (ramp_samples - n_used) // 2
    out = np.empty((n_pix, 2), np.int64)
    for k in range(2):
        r0 = k * ramp_samples + off
        ramp = codes[:, 0, r0:r0 + n_used].astype(np.float32) * window
        p = np.abs(np.fft.rfft(ramp, axis=-1)) ** 2
        out[:, k] = p.reshape(n_pix, averages, -1).mean(axis=1).argmax(axis=-1)
    return out


def _write_points(path: str, n_points: int) -> None:
    """A binary little-endian PLY of n_points (x, y, z float32, intensity float32)."""
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    pts = np.zeros(n_points, dt)
    head = ("ply\nformat binary_little_endian 1.0\n"
            f"element vertex {n_points}\nproperty float x\nproperty float y\nproperty float z\n"
            "property float intensity\nend_header\n").encode()
    with open(path, "wb") as f:
        f.write(head)
        pts.tofile(f)


def run_limit(pixels: int, averages: int, record_length: int, ramp_samples: int, *, channels: int = 1,
              points: int | None = None, use_fraction: float = 0.9, fs_hz: float = 5e6,
              chunk_samples: int = 4_000_000, seed: int = 0) -> dict:
    """Time the limit kernel of that scan; per-stage wall and CPU seconds and the totals."""
    rng = np.random.default_rng(seed)
    n_used = int(ramp_samples * use_fraction) & ~1
    window = np.hanning(n_used).astype(np.float32)
    clock = _Clock()
    # whole pixels per chunk, so a pixel's averages are in one chunk
    pix_per_chunk = max(1, chunk_samples // (averages * record_length * channels))
    for p0 in range(0, pixels, pix_per_chunk):
        n_pix = min(pix_per_chunk, pixels - p0)
        codes = clock.run("synthesis", _synth, rng, n_pix * averages, record_length, channels, fs_hz)
        raw = codes.tobytes()
        got = clock.run("transport", lambda: np.frombuffer(raw, np.int16).reshape(codes.shape).copy())
        clock.run("dsp", _dsp, got, averages, ramp_samples, n_used, window)
    n_points = pixels if points is None else points
    with tempfile.TemporaryDirectory(prefix="limit-") as d:
        clock.run("points", _write_points, os.path.join(d, "limit.ply"), n_points)
    return {"pixels": pixels, "averages": averages, "record_length": record_length, "channels": channels,
            "ramp_samples": ramp_samples, "n_used": n_used, "points": n_points,
            "samples": pixels * averages * record_length * channels,
            "wall_s": clock.wall, "cpu_s": clock.cpu,
            "total_wall_s": sum(clock.wall.values()), "total_cpu_s": sum(clock.cpu.values())}


def stage_ratios(scan_s: dict, limit_s: dict) -> dict:
    """scan / limit per stage present in both (and in total over those stages)."""
    out = {k: scan_s[k] / limit_s[k] for k in STAGES if k in scan_s and limit_s.get(k, 0) > 0}
    both = [k for k in STAGES if k in scan_s and k in limit_s]
    out["total"] = sum(scan_s[k] for k in both) / max(sum(limit_s[k] for k in both), 1e-12)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--pixels", type=int, default=12288)
    ap.add_argument("--averages", type=int, default=10)
    ap.add_argument("--record-length", type=int, default=800)
    ap.add_argument("--ramp-samples", type=int, default=400)
    ap.add_argument("--channels", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    r = run_limit(a.pixels, a.averages, a.record_length, a.ramp_samples, channels=a.channels)
    if a.json:
        print(json.dumps(r))
        return
    print(f"limit kernel: {r['pixels']} px x {r['averages']} avg x {r['record_length']} samples "
          f"x {r['channels']} ch = {r['samples'] / 1e6:.1f} M samples")
    for k in STAGES:
        print(f"  {k:10s} wall {r['wall_s'][k]:.3f} s  cpu {r['cpu_s'][k]:.3f} s")
    print(f"  total      wall {r['total_wall_s']:.3f} s  cpu {r['total_cpu_s']:.3f} s")


if __name__ == "__main__":
    main()
