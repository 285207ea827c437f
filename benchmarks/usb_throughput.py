"""Digitizer throughput through the simulated USB path (in-process and across processes).

§4.4.1 chirps: 80 us per chirp; at 250 MS/s that is 20 000 samples per channel per segment
(beat + MZI, int16 -> 80 kB per pixel). A 128 x 128 FPSA frame is 16 384 segments (1.3 GB), so the
simulated transfer must not be what limits a frame: target >= 200 MB/s in-process.

Measures wall-clock MB/s of ``DigitizerDriver.read_segments`` (driver parsing, crc checks and
the simulator's framing included; the segment source returns precomputed codes so the world model
is not what is measured). Run: ``python benchmarks/usb_throughput.py``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

import numpy as np
import usb.core

from drivers.digitizer import protocol as p
from drivers.digitizer.driver import DigitizerDriver
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.device import CapturedSegments, SimDigitizer
from sim_devices.usb.backend import RemoteUsbBackend, SimUsbBackend, UsbBridgeServer

RATE_HZ = 250e6
RECORD = 20_000
CHANNELS = ("beat", "mzi")


class PrecomputedSource:
    """Same noisy tone block for every segment; only trigger times differ."""

    def __init__(self, max_count: int = 256) -> None:
        rng = np.random.default_rng(1)
        t = np.arange(RECORD) / RATE_HZ
        one = np.stack([np.rint(8000 * np.sin(2 * np.pi * 12.5e6 * t) + rng.normal(0, 30, RECORD)),
                        np.rint(8000 * np.cos(2 * np.pi * 3e6 * t))]).astype(np.int16)
        self._block = np.broadcast_to(one, (max_count, 2, RECORD))
        self._over = np.zeros((max_count, 2), bool)

    def capture(self, first, count, cfg):
        return CapturedSegments(np.arange(first, first + count) * 100e-6, self._block[:count],
                                self._over[:count])


def make_sim() -> SimDigitizer:
    return SimDigitizer(VirtualClock(), PrecomputedSource())


def measure(driver: DigitizerDriver, total_segments: int, per_read: int) -> tuple[float, float]:
    cfg = driver.configure(channels=CHANNELS, sample_rate_hz=RATE_HZ, record_length=RECORD,
                           segments=total_segments, bits=16, input_range_v=1.0)
    driver.arm()
    driver.read_segments(0, 2, cfg)  # warm-up (allocations, first batch)
    driver.arm()
    nbytes = 0
    t0 = time.perf_counter()
    for first in range(0, total_segments, per_read):
        count = min(per_read, total_segments - first)
        _, s = driver.read_segments(first, count, cfg)
        nbytes += count * p.segment_bytes(len(CHANNELS), RECORD, 16)
    dt = time.perf_counter() - t0
    assert s.shape == (count, 2, RECORD)
    return nbytes / dt / 1e6, nbytes / 1e6


def serve() -> None:
    """Bench side of the cross-process measurement: print the port, serve until stdin closes."""
    server = UsbBridgeServer([make_sim()])
    print(server.port, flush=True)
    sys.stdin.read()
    server.close()


def run_usb(segments: int = 2000, per_read: int = 256, subprocess_bench: bool = True) -> dict:
    """MB/s in-process, across a bridge thread and (optionally) across a bench subprocess."""
    out = {"segment_kb": p.segment_bytes(len(CHANNELS), RECORD, 16) / 1e3, "segments": segments,
           "per_read": per_read}
    dev = usb.core.find(idVendor=p.DIGITIZER_VID, idProduct=p.DIGITIZER_PID,
                        backend=SimUsbBackend([make_sim()]))
    out["inproc_mb_s"], out["mb"] = measure(DigitizerDriver(dev), segments, per_read)

    server = UsbBridgeServer([make_sim()])
    backend = RemoteUsbBackend(f"tcp://127.0.0.1:{server.port}")
    try:
        dev = usb.core.find(idVendor=p.DIGITIZER_VID, idProduct=p.DIGITIZER_PID, backend=backend)
        out["bridge_thread_mb_s"], _ = measure(DigitizerDriver(dev), segments, per_read)
    finally:
        backend.close()
        server.close()

    if subprocess_bench:
        proc = subprocess.Popen([sys.executable, __file__, "--serve"], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, text=True)
        try:
            port = int(proc.stdout.readline())
            backend = RemoteUsbBackend(f"tcp://127.0.0.1:{port}")
            dev = usb.core.find(idVendor=p.DIGITIZER_VID, idProduct=p.DIGITIZER_PID, backend=backend)
            out["bridge_subprocess_mb_s"], _ = measure(DigitizerDriver(dev), segments, per_read)
            backend.close()
        finally:
            proc.stdin.close()
            proc.wait(timeout=30)
    out["frame_128x128_gb"] = 128 * 128 * out["segment_kb"] / 1e6
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--serve", action="store_true", help="internal: run the bench side")
    ap.add_argument("--segments", type=int, default=2000)
    ap.add_argument("--per-read", type=int, default=256)
    args = ap.parse_args(argv)
    if args.serve:
        serve()
        return
    print(f"segment: {len(CHANNELS)} ch x {RECORD} samples int16 = "
          f"{p.segment_bytes(len(CHANNELS), RECORD, 16) / 1e3:.1f} kB; "
          f"{args.segments} segments, {args.per_read} per read_segments call")
    r = run_usb(args.segments, args.per_read)
    print(f"in-process (SimUsbBackend):            {r['inproc_mb_s']:8.1f} MB/s  ({r['mb']:.0f} MB)  target >= 200")
    print(f"bridge, server thread same process:   {r['bridge_thread_mb_s']:8.1f} MB/s  ({r['mb']:.0f} MB)")
    print(f"bridge, bench in a subprocess (TCP):  {r['bridge_subprocess_mb_s']:8.1f} MB/s  ({r['mb']:.0f} MB)")
    print(f"a 128x128 frame is {r['frame_128x128_gb']:.2f} GB of samples at this record length")


if __name__ == "__main__":
    main()
