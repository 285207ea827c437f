"""Fingerprint of the simulated bench's bytes and a calibrated scan's points (sha256 digests).

``python -m benchmarks.bench_identity`` prints one digest per line: the digitizer's captured codes of a
lit bench (plain, with an overrange and a mid-batch interlock fault), the fault records, and the points
of a linearized ROI scan on config/sim.toml. Two commits that print the same lines give bit-identical
benches and scans: a refactoring of the simulator or the store must not change a digit.
"""

from __future__ import annotations

import hashlib
import threading
from pathlib import Path

import numpy as np

from lidard.config import load_config
from lidard.instrument.compose import open_instrument
from lidard.instrument.types import ScanRequest

ROOT = Path(__file__).resolve().parents[1]


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def bench_bytes() -> list[str]:
    import sys
    sys.path.insert(0, str(ROOT))
    from sim_devices.digitizer.device import CaptureConfig
    from tests.helpers.sim_bench import lit_bench

    out = []
    pixels = [(r, c) for r in (60, 62) for c in range(60, 76)]
    with lit_bench({}, pixels) as b:
        cap = CaptureConfig(sample_rate_hz=b.cfg.adc.max_sample_rate_hz, record_length=1024, channels=("beat", "mzi", "tap"),
                            input_range_v=b.cfg.adc.input_range_v, bits=b.cfg.adc.bits)
        s = b.capture(0, 16, cap)
        out.append("plain " + _digest(s.codes, s.overrange, s.trigger_time_s))
        b.inject_fault("digitizer_overrange", gain=40.0)
        b.inject_fault("interlock_open", after_segments=5)
        s = b.capture(16, 16, cap)
        out.append("faulted " + _digest(s.codes, s.overrange, s.trigger_time_s))
        out.append("faults " + hashlib.sha256(repr(sorted((f["kind"], f["id"]) for f in b.active_faults())).encode()
                                               ).hexdigest()[:16])
        out.append(f"cleared {b.clear_faults()}")
    return out


def scan_points() -> list[str]:
    cfg = load_config(ROOT / "config" / "sim.toml")
    inst = open_instrument(cfg, bench="embedded")
    try:
        cal = inst.linearize()
        res = inst.run_scan(ScanRequest(pattern="roi", rows=(56, 72), cols=(56, 72), max_range_m=10.0),
                            lambda p: None, threading.Event(), cal)
        p = res.points
        return ["scan " + _digest(*(p[n] for n in p.dtype.names)) + f" ({len(p)} points)"]
    finally:
        inst.close()


def main() -> int:
    for line in bench_bytes() + scan_points():
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
