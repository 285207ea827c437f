"""A/B of the frame DSP's CPU time between two trees, alternated (the machine is shared): each round runs
benchmarks/frame_dsp_cpu.py ``one`` and ``two`` in a fresh process with each tree on PYTHONPATH, one BLAS
thread, and prints per tree the median of the rounds' best-of-3 CPU times, the B / A ratios, and the
two-return frame against tree A's single-return frame.

    python benchmarks/frame_dsp_ab.py /work/main $PWD [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path
from statistics import median

SCRIPT = Path(__file__).with_name("frame_dsp_cpu.py")


def one_run(tree: str, kind: str) -> float:
    env = dict(os.environ, PYTHONPATH=tree, OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, str(SCRIPT), kind], env=env, capture_output=True, text=True, check=True)
    m = re.search(r"([0-9.]+) s CPU", out.stdout)
    if m is None:
        raise RuntimeError(f"frame_dsp_cpu.py printed no CPU time: {out.stdout!r} {out.stderr[-500:]!r}")
    return float(m.group(1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tree_a")
    ap.add_argument("tree_b")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    times: dict[tuple[str, str], list[float]] = {}
    loads = []
    for _ in range(args.rounds):
        for tree in (args.tree_a, args.tree_b):
            for kind in ("one", "two"):
                times.setdefault((tree, kind), []).append(one_run(tree, kind))
                loads.append(os.getloadavg()[0])
    med = {k: median(v) for k, v in times.items()}
    a, b = args.tree_a, args.tree_b
    print(f"rounds {args.rounds}, load average {min(loads):.1f}-{max(loads):.1f}")
    print("| frame | A CPU s (median) | B CPU s (median) | B / A | / A's one-return frame (A, B) |")
    print("|---|---:|---:|---:|---|")
    for kind in ("one", "two"):
        print(f"| {kind} return(s) | {med[(a, kind)]:.3f} | {med[(b, kind)]:.3f} | {med[(b, kind)] / med[(a, kind)]:.2f} "
              f"| {med[(a, kind)] / med[(a, 'one')]:.2f}, {med[(b, kind)] / med[(a, 'one')]:.2f} |")


if __name__ == "__main__":
    main()
