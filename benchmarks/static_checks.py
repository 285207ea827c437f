"""Findings of the static checks on a tree, as pyproject.toml configures them: ruff, mypy, and the
tracker references ("issue N") in production code.

    python benchmarks/static_checks.py                  # this tree
    python benchmarks/static_checks.py --tree /tmp/base # another checkout, with THIS tree's config

For a tree from before the checks were configured, its pyproject.toml is replaced by this one's
first (the tool configuration is what is compared, not the tree's own defaults).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TRACKER_REF = re.compile(r"\bissues? #?\d+", re.IGNORECASE)


def ruff_findings(tree: Path) -> int:
    r = subprocess.run([sys.executable, "-m", "ruff", "check", ".", "--no-cache", "--output-format", "concise"],
                       cwd=tree, capture_output=True, text=True, check=False)
    return sum(1 for line in r.stdout.splitlines() if re.match(r"^\S+:\d+:\d+: ", line))


def mypy_findings(tree: Path) -> tuple[int, float]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    cache = tree / ".mypy_cache_static_checks"
    t0 = time.process_time()
    r = subprocess.run([sys.executable, "-m", "mypy", "--cache-dir", str(cache)], cwd=tree, env=env,
                       capture_output=True, text=True, check=False)
    cpu = time.process_time() - t0 + sum(os.times()[2:4])
    shutil.rmtree(cache, ignore_errors=True)
    return sum(1 for line in r.stdout.splitlines() if ": error:" in line), cpu


def tracker_refs(tree: Path) -> tuple[int, int]:
    hits, files = 0, 0
    for top in ("lidard", "drivers", "sim_devices"):
        for path in (tree / top).rglob("*.py"):
            n = len(TRACKER_REF.findall(path.read_text(encoding="utf-8", errors="replace")))
            hits, files = hits + n, files + (n > 0)
    return hits, files


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", type=Path, default=ROOT)
    args = ap.parse_args()
    tree = args.tree.resolve()
    if tree != ROOT:
        shutil.copy(ROOT / "pyproject.toml", tree / "pyproject.toml")
    refs, ref_files = tracker_refs(tree)
    mypy, cpu = mypy_findings(tree)
    print("| tree | ruff findings | mypy errors | 'issue N' in production code (files) | mypy CPU s |")
    print("|---|---:|---:|---:|---:|")
    print(f"| {tree} | {ruff_findings(tree)} | {mypy} | {refs} ({ref_files}) | {cpu:.1f} |")


if __name__ == "__main__":
    main()
