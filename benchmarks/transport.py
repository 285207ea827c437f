"""The digitizer transport of a frame scan against its limit kernel (issue 18, transport stage).

What a frame scan's "transport" stage is (benchmarks/frame.py: ``AcquisitionLifecycle.read`` minus the
bench's capture): the simulated digitizer framing the source's codes (front end, headers, CRCs),
the bulk-IN transfers through the pyusb backend, and the driver's checks and parsing
(drivers/digitizer/driver.py). The limit kernel of that stage (benchmarks/limit.py) is one copy of
the int16 records out of a byte buffer.

Here the segment source returns precomputed codes (the world model is not measured) and the
records have the frame benchmark's geometry (CAL letters at 2 m, one beat channel, 16-bit format,
anti-alias corner 500 MHz: no filtering; triangle 5 MS/s x 800 samples at 16-bit resolution, or
``--chirp three_segment`` 40 MS/s x 9,520 samples at 14 bits, or ``--chirp default_band`` the
three-segment chirp at the default 0.4 m/s band: 5 MS/s x 1,190 samples at 16 bits, read 200 at a time),
read ``per_read`` segments at a time as the scan reads them (its 50 ms safety-check batches:
31 pixels x 10 averages, or 303 pixels x 1). Prints CPU seconds of the reads and of the limit's
copy, and their ratio (one process, so the ratio does not move with the machine's load).

    python benchmarks/transport.py [--chirp triangle|three_segment|default_band] [--segments 122880] [--per-read 310] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import usb.core

from drivers.digitizer import protocol as p
from drivers.digitizer.driver import DigitizerDriver
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.device import CapturedSegments, SimDigitizer
from sim_devices.usb.backend import SimUsbBackend

PERIOD_S = 160e-6
#: record geometries of the frame benchmark's chirps (CAL letters, 2 m): rate, samples per record,
#: the record resolution the configuration gives at that rate (lidard.config ADC.record_bits)
GEOMETRIES = {"triangle": (5e6, 800, 16), "three_segment": (40e6, 9520, 14),
              # the default band of config/sim.toml (scan.max_speed_mps 0.4): 5 MS/s x 1,190 samples,
              # read 20 pixels x 10 averages at a time (50 ms of hardware time)
              "default_band": (5e6, 1190, 16)}


class CodesSource:
    """The same block of noisy codes for every request (only the trigger times differ)."""

    def __init__(self, channels: int, max_count: int, record: int) -> None:
        rng = np.random.default_rng(1)
        one = np.rint(rng.normal(0, 3000, (max_count, channels, record))).astype(np.int16)
        self._block = one
        self._over = np.zeros((max_count, channels), bool)

    def capture(self, first, count, cfg):
        return CapturedSegments(np.arange(first, first + count) * PERIOD_S, self._block[:count],
                                self._over[:count])


def run_transport(segments: int = 122_880, per_read: int = 310, channels: int = 1,
                  bandwidth_hz: float = 500e6, chirp: str = "triangle") -> dict:
    """CPU seconds of reading ``segments`` through the simulated USB path, and of the limit's copy."""
    rate_hz, record, resolution_bits = GEOMETRIES[chirp]
    names = ("beat", "mzi", "mzi_q")[:channels]
    sim = SimDigitizer(VirtualClock(), CodesSource(channels, per_read, record))
    dev = usb.core.find(idVendor=p.DIGITIZER_VID, idProduct=p.DIGITIZER_PID, backend=SimUsbBackend([sim]))
    drv = DigitizerDriver(dev)
    cfg = drv.configure(channels=names, sample_rate_hz=rate_hz, record_length=record, segments=segments,
                        bits=16, resolution_bits=resolution_bits, bandwidth_hz=bandwidth_hz)
    drv.arm()
    _, first_batch = drv.read_segments(0, min(per_read, segments), cfg)   # warm-up: first allocations
    c = time.process_time()
    for first in range(0, segments, per_read):
        _, samples = drv.read_segments(first, min(per_read, segments - first), cfg)
    scan_cpu = time.process_time() - c
    # the limit: one copy of the same int16 records out of a byte buffer, batch by batch
    raw = first_batch.tobytes()
    c = time.process_time()
    for first in range(0, segments, per_read):
        n = min(per_read, segments - first)
        np.frombuffer(raw, np.int16, count=n * channels * record).copy()
    limit_cpu = time.process_time() - c
    mb = segments * p.segment_bytes(channels, record, 16) / 1e6
    return {"segments": segments, "per_read": per_read, "channels": channels, "mb": mb, "chirp": chirp,
            "record_length": record, "resolution_bits": resolution_bits,
            "scan_cpu_s": scan_cpu, "limit_cpu_s": limit_cpu, "ratio": scan_cpu / max(limit_cpu, 1e-12),
            "mb_per_cpu_s": mb / max(scan_cpu, 1e-12)}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--segments", type=int, default=122_880, help="12,288 pixels x 10 averages")
    ap.add_argument("--per-read", type=int, default=310, help="segments per read_segments call")
    ap.add_argument("--channels", type=int, default=1, choices=(1, 2, 3))
    ap.add_argument("--chirp", default="triangle", choices=tuple(GEOMETRIES),
                    help="record geometry: triangle 5 MS/s x 800 at 16 bits, three_segment 40 MS/s x 9,520 at 14")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    r = run_transport(a.segments, a.per_read, a.channels, chirp=a.chirp)
    if a.json:
        print(json.dumps(r))
        return
    print(f"{r['chirp']}: {r['segments']} segments x {a.channels} ch x {r['record_length']} samples at "
          f"{r['resolution_bits']} bits ({r['mb']:.0f} MB), "
          f"{r['per_read']} per read: transport {r['scan_cpu_s']:.3f} s CPU ({r['mb_per_cpu_s']:.0f} MB/s), "
          f"limit copy {r['limit_cpu_s']:.3f} s, ratio {r['ratio']:.1f}x")


if __name__ == "__main__":
    main()
