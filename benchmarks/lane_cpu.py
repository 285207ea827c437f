"""CPU time of every test of a lane (default the quick lane, ``-m "not slow"``), summed, and the tests
that cost the most.

    python benchmarks/lane_cpu.py [--marker "not slow"] [--json lane.json] [--over 3] tests/dsp tests/physics ...

The tests run in one ``nice pytest -n 0 -p no:randomly`` per path given (slices of the suite, so a
shared machine is never asked for the whole suite at once), with this module loaded as a pytest plugin
that records, per test, the CPU (user + sys of the pytest process and of the children it waited for)
and the wall time of its setup, call and teardown. CPU, not wall time: on a busy machine the wall
clock measures the neighbours. The lane's wall time on an idle machine with ``pytest -n 2`` is about
the summed CPU / 2 (its two workers, each a core; work stealing keeps them busy to the end) plus the
workers' start-up. Prints the sum per slice and overall, the load, and every test over ``--over``
seconds of CPU (slow-marker candidates), slowest first.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
_OUT_ENV = "LANE_CPU_OUT"


def _cpu() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


# -- pytest plugin (loaded with -p benchmarks.lane_cpu) ---------------------------------------------
_records: dict[str, list[float]] = {}


def pytest_runtest_protocol(item: Any, nextitem: Any) -> None:
    item._lane_cpu_start = (_cpu(), time.monotonic())


def pytest_runtest_makereport(item: Any, call: Any) -> None:
    if call.when == "teardown" and hasattr(item, "_lane_cpu_start"):
        cpu0, wall0 = item._lane_cpu_start
        _records[item.nodeid] = [_cpu() - cpu0, time.monotonic() - wall0]


def pytest_sessionfinish(session: Any, exitstatus: int) -> None:
    out = os.environ.get(_OUT_ENV)
    if out:
        Path(out).write_text(json.dumps(_records))


# -- driver -----------------------------------------------------------------------------------------
def run_slice(path: str, marker: str, tree: Path) -> tuple[dict[str, list[float]], str, float]:
    """(per-test [cpu_s, wall_s], pytest's last line, slice wall s) of one path."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "lane.json"
        env = {**os.environ, "PYTHONPATH": str(tree), _OUT_ENV: str(out)}
        t0 = time.monotonic()
        proc = subprocess.run(["nice", sys.executable, "-m", "pytest", "-n", "0", "-q", "-p", "no:randomly",
                               "-p", "no:cacheprovider", "-p", "benchmarks.lane_cpu", "-m", marker, path],
                              cwd=tree, env=env, capture_output=True, text=True)
        wall = time.monotonic() - t0
        recs = json.loads(out.read_text()) if out.exists() else {}
    lines = [ln for ln in proc.stdout.splitlines() if ln.strip()]
    return recs, (lines[-1] if lines else f"exit {proc.returncode}"), wall


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="+", help="test paths, one pytest run each (relative to the tree)")
    ap.add_argument("--marker", default="not slow", help="the lane's -m expression")
    ap.add_argument("--tree", type=Path, default=REPO, help="checkout to run the tests in")
    ap.add_argument("--over", type=float, default=3.0, help="list the tests over this many CPU seconds")
    ap.add_argument("--json", default=None, help="also write every test's [cpu_s, wall_s] here")
    args = ap.parse_args(argv)
    if args.over < 0:
        ap.error(f"--over must be >= 0 seconds, got {args.over}")
    every: dict[str, list[float]] = {}
    print(f"| slice | tests | CPU s | wall s | load (1 min) | pytest |   lane -m {args.marker!r}, tree {args.tree}")
    print("|---|---:|---:|---:|---:|---|")
    for path in args.paths:
        load = os.getloadavg()[0]
        recs, last, wall = run_slice(path, args.marker, args.tree.resolve())
        every.update(recs)
        print(f"| {path} | {len(recs)} | {sum(c for c, _ in recs.values()):.1f} | {wall:.0f} | {load:.1f} | {last} |",
              flush=True)
    total = sum(c for c, _ in every.values())
    print(f"\nall slices: {len(every)} tests, {total:.1f} s CPU (idle pytest -n 2: about {total / 2:.0f} s "
          "plus the workers' start-up)")
    heavy = sorted(((c, w, n) for n, (c, w) in every.items() if c > args.over), reverse=True)
    print(f"\ntests over {args.over:g} s CPU ({len(heavy)}, {sum(c for c, _, _ in heavy):.1f} s):")
    for c, w, n in heavy:
        print(f"  {c:6.1f} s CPU {w:6.1f} s wall  {n}")
    if args.json:
        Path(args.json).write_text(json.dumps(every, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
