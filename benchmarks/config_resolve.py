"""CPU per use of a loaded configuration's presets (profile, optics, laser preset): what every caller
of ``cfg.load_profile()`` / ``cfg.optics()`` / ``cfg.load_laser()`` pays once the file is loaded.

    python benchmarks/config_resolve.py [--config config/sim.toml] [--n 20000]

Run it on two trees (PYTHONPATH=<tree>) to compare; the figure is CPU time (time.process_time), so
it holds under a shared machine's load better than wall time.
"""

from __future__ import annotations

import argparse
import time

from lidard.config import load_config


def per_use_us(path: str, n: int) -> float:
    cfg = load_config(path)
    cfg.load_profile(), cfg.optics(), cfg.load_laser()          # the first use reads the files
    t0 = time.process_time()
    for _ in range(n):
        cfg.load_profile(), cfg.optics(), cfg.load_laser()
    return (time.process_time() - t0) / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="config/sim.toml")
    ap.add_argument("--n", type=int, default=20000)
    args = ap.parse_args()
    print(f"{per_use_us(args.config, args.n):.1f} us CPU per (load_profile, optics, load_laser)")


if __name__ == "__main__":
    main()
