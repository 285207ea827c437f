"""CPU (user + sys, children included) of single test files, run one at a time with ``pytest -n 0``.

    python -m benchmarks.suite_cpu [--tree DIR] tests/e2e/test_e2e_phase_noise.py ...

Each file runs in its own ``nice pytest -n 0 -q -p no:cacheprovider`` subprocess from ``--tree`` (default:
this tree) with PYTHONPATH set to that tree, so an A/B of two checkouts (``git archive main | tar -x -C
/tmp/main``) measures both versions of a test on the same machine. CPU time, not wall time: on a shared
machine the wall clock measures the neighbours. Prints one markdown row per file with the load.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
from pathlib import Path


def measure(tree: Path, test: str) -> tuple[float, float, str]:
    """(cpu_s, wall_s, outcome line) of one test file's pytest run in ``tree``."""
    import time
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    proc = subprocess.run(["nice", sys.executable, "-m", "pytest", "-n", "0", "-q", "-p", "no:cacheprovider", test],
                          cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)}, capture_output=True, text=True)
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    lines = [ln for ln in proc.stdout.splitlines() if ln.strip()]
    return cpu, wall, (lines[-1] if lines else f"exit {proc.returncode}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", type=Path, default=Path.cwd(), help="checkout to run the tests in")
    ap.add_argument("tests", nargs="+", help="test files (paths relative to the tree)")
    args = ap.parse_args(argv)
    print(f"| test file | CPU s (user+sys) | wall s | load (1 min) | outcome |  tree {args.tree}")
    print("|---|---:|---:|---:|---|")
    for test in args.tests:
        load = os.getloadavg()[0]
        cpu, wall, outcome = measure(args.tree.resolve(), test)
        print(f"| {test} | {cpu:.1f} | {wall:.0f} | {load:.1f} | {outcome} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
