"""Benchmark: upload a full 12,288-pixel pattern (128 columns x 96 bonded rows, §4.3.3) to the
FPSA controller and report bytes on the wire, modelled UART time, and wall time.

Modelled time is the simulated FPGA's virtual clock: every byte costs 10 bit times at the
configured baud (8N1). Wall time is measured through a real pty (driver -> pyserial -> kernel
pty -> simulator thread) and through the in-memory pipe, so the Python overhead of the codec
and of the pty round trips are visible separately.

Default 3,000,000 baud: the Cmod-S7's FT2232H can do 12 Mbaud, but 3 Mbaud divides both the
FTDI baud base and a 48 MHz FPGA UART clock exactly (docs/protocols/fpsa.md, "Physical link").

    python benchmarks/pattern_upload.py [--baud 3000000] [--chunk 1024] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drivers.fpsa import protocol as p
from drivers.fpsa.driver import FpsaController, FpsaLink
from sim_devices.clock import VirtualClock
from sim_devices.fpsa.device import FpgaConfig, FpgaSim, default_bonded_rows


def raster() -> np.ndarray:
    rows = np.array(default_bonded_rows(128))
    rr, cc = np.meshgrid(rows, np.arange(128), indexing="ij")
    return np.stack([rr.ravel(), cc.ravel()], axis=1)


def one_upload(baud: int, chunk: int, via_pty: bool) -> dict[str, float]:
    clock = VirtualClock()
    sim = FpgaSim(clock, FpgaConfig(baudrate=baud))
    pattern = raster()
    server = sim.serve_pty() if via_pty else None
    try:
        link = FpsaLink(timeout_s=2.0, chunk_pixels=chunk)
        drv = (FpsaController.from_url(server.path, baudrate=baud, link=link)
               if server else FpsaController(sim.open_pipe(), link=link))
        drv.reset()
        rx0, tx0, t_virtual0 = sim.rx_bytes, sim.tx_bytes, clock.now()
        t0 = time.perf_counter()
        n_chunks = drv.upload_pattern(pattern)
        wall = time.perf_counter() - t0
        modelled = clock.now() - t_virtual0
        drv.close()
    finally:
        if server:
            server.close()
    assert sim.status().faults == p.FaultFlag.NONE
    return {"chunks": n_chunks, "host_to_fpga_B": sim.rx_bytes - rx0,
            "fpga_to_host_B": sim.tx_bytes - tx0, "modelled_s": modelled, "wall_s": wall}


def run_upload(baud: int = 3_000_000, chunk: int = 1024, repeat: int = 3) -> dict:
    """Wire bytes, modelled UART time and wall time (pty and pipe); modelled time at other bauds."""
    n = raster().shape[0]
    out: dict = {"pixels": n, "payload_B": 2 * n, "baud": baud, "chunk": chunk}
    for via_pty in (True, False):
        runs = [one_upload(baud, chunk, via_pty) for _ in range(repeat)]
        r = runs[0]
        walls = sorted(x["wall_s"] for x in runs)
        total = r["host_to_fpga_B"] + r["fpga_to_host_B"]
        out["pty" if via_pty else "pipe"] = {
            **r, "overhead_pct": 100 * (total / (2 * n) - 1), "wall_median_s": walls[len(walls) // 2],
            "wall_min_s": walls[0]}
    out["modelled_s_by_baud"] = {b: one_upload(b, chunk, via_pty=False)["modelled_s"]
                                 for b in (115_200, 1_000_000, 3_000_000, 12_000_000)}
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baud", type=int, default=3_000_000)
    ap.add_argument("--chunk", type=int, default=1024, help="pixels per PATTERN_CHUNK")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    res = run_upload(args.baud, args.chunk, args.repeat)
    print(f"pattern: {res['pixels']} pixels (96 bonded rows x 128 columns), payload {res['payload_B']} B raw")
    print(f"link: {args.baud} baud 8N1, {args.chunk} pixels per chunk")
    for key in ("pty", "pipe"):
        r = res[key]
        print(f"[{key:4s}] chunks {r['chunks']}, host->fpga "
              f"{r['host_to_fpga_B']} B, fpga->host {r['fpga_to_host_B']} B "
              f"(overhead {r['overhead_pct']:.2f} %), modelled wire time "
              f"{1e3 * r['modelled_s']:.2f} ms, wall median {1e3 * r['wall_median_s']:.2f} ms "
              f"(min {1e3 * r['wall_min_s']:.2f} ms)")
    for baud, t in res["modelled_s_by_baud"].items():
        print(f"modelled at {baud:>10} baud: {1e3 * t:9.2f} ms")


if __name__ == "__main__":
    main()
