"""Cost of the simulated digitizer's front end (anti-alias filter, resolution quantizer) and of the
COBS framing of the FPSA link, per sample / per frame.

The front end runs only when the host asks for it (SET_BANDWIDTH below fs/2, SET_RESOLUTION below
the format's bits); this prints what it costs then, in samples per second, to set against the beat
synthesis it follows (benchmarks/synthesis.py, ~40 M samples/s per core without phase noise).
COBS: microseconds per maximum-size (4 KiB payload) frame, encode and decode, through the ``cobs``
package that drivers/fpsa/protocol.py uses. Run: ``python benchmarks/digitizer_front_end.py``.
"""

from __future__ import annotations

import os
import time

import numpy as np

from drivers.digitizer import protocol as p
from drivers.fpsa import protocol as fp
from sim_devices.digitizer.device import front_end


def _rate(fn, n_items: float, repeat: int) -> float:
    fn()  # warm up (filter design, allocations)
    t0 = time.perf_counter()
    for _ in range(repeat):
        fn()
    return n_items * repeat / (time.perf_counter() - t0)


def main() -> None:
    rng = np.random.default_rng(0)
    # one 4 MiB simulator batch: 100 segments of 20 000 int16 samples (80 us at 250 MS/s)
    codes = rng.normal(0.0, 1000.0, (100, 1, 20_000)).round().astype(np.int16)
    base = dict(sample_rate_hz=250_000_000, record_length=20_000, segments=100, input_range_mv=1000,
                channel_mask=1, bits=16)
    filt = p.Config(**base, resolution_bits=16, bandwidth_hz=50_000_000)
    quant = p.Config(**base, resolution_bits=12, bandwidth_hz=0)
    both = p.Config(**base, resolution_bits=12, bandwidth_hz=50_000_000)
    for name, cfg in [("band limit (50 MHz of 125 MHz Nyquist)", filt), ("12-bit quantizer", quant),
                      ("band limit + quantizer", both)]:
        rate = _rate(lambda c=cfg: front_end(codes, c), codes.size, 5)
        print(f"{name:40s} {rate / 1e6:8.1f} M samples/s")
    payload = os.urandom(fp.MAX_PAYLOAD)
    inner = fp.encode_inner(1, fp.Cmd.PATTERN_CHUNK, payload)
    enc = fp.cobs_encode(inner)
    for name, fn in [("COBS encode, 4 KiB frame", lambda: fp.cobs_encode(inner)),
                     ("COBS decode, 4 KiB frame", lambda: fp.cobs_decode(enc))]:
        per_s = _rate(fn, 1, 2000)
        print(f"{name:40s} {1e6 / per_s:8.1f} us per frame")


if __name__ == "__main__":
    main()
