"""Findings of the static checks on a tree, as pyproject.toml configures them: ruff, mypy, the
tracker references ("issue N") in production code, and the functions whose signature has grown past
``MAX_PARAMS`` parameters (each listed with --long; tests/test_static_checks.py holds their count).

    python benchmarks/static_checks.py                  # this tree
    python benchmarks/static_checks.py --tree /tmp/base # another checkout, with THIS tree's config
    python benchmarks/static_checks.py --long           # ... and list the long signatures

For a tree from before the checks were configured, its pyproject.toml is replaced by this one's
first (the tool configuration is what is compared, not the tree's own defaults).
"""

from __future__ import annotations

import argparse
import ast
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TRACKER_REF = re.compile(r"\bissues? #?\d+", re.IGNORECASE)
# a signature past this many parameters (self/cls not counted, *args/**kwargs counted) wants a
# parameter object (a frozen dataclass of settings)
MAX_PARAMS = 8
PRODUCTION = ("lidard", "drivers", "sim_devices")


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


def _compiled(node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    """A numba kernel (decorated ``jit``/``njit``/``_jit``): it takes flat arrays and scalars because
    numba compiles no parameter objects, so its signature is not counted."""
    return any(ast.unparse(d.func if isinstance(d, ast.Call) else d).split(".")[-1].lstrip("_") in ("jit", "njit")
               for d in node.decorator_list)


def long_signatures(tree: Path, limit: int = MAX_PARAMS) -> list[tuple[int, str]]:
    """(parameters, "path:line name") of every function or method of the production code taking more
    than ``limit`` parameters, most first."""
    out = []
    for top in PRODUCTION:
        for path in sorted((tree / top).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) or _compiled(node):
                    continue
                a = node.args
                names = [x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
                if names and names[0] in ("self", "cls"):
                    names = names[1:]
                n = len(names) + (a.vararg is not None) + (a.kwarg is not None)
                if n > limit:
                    out.append((n, f"{path.relative_to(tree)}:{node.lineno} {node.name}"))
    return sorted(out, key=lambda t: (-t[0], t[1]))


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
    ap.add_argument("--long", action="store_true", help=f"list the signatures of more than {MAX_PARAMS} parameters")
    args = ap.parse_args()
    tree = args.tree.resolve()
    if tree != ROOT:
        shutil.copy(ROOT / "pyproject.toml", tree / "pyproject.toml")
    refs, ref_files = tracker_refs(tree)
    mypy, cpu = mypy_findings(tree)
    long = long_signatures(tree)
    print(f"| tree | ruff findings | mypy errors | 'issue N' in production code (files) "
          f"| signatures > {MAX_PARAMS} parameters (most) | mypy CPU s |")
    print("|---|---:|---:|---:|---:|---:|")
    print(f"| {tree} | {ruff_findings(tree)} | {mypy} | {refs} ({ref_files}) "
          f"| {len(long)} ({long[0][0] if long else 0}) | {cpu:.1f} |")
    if args.long:
        print()
        for n, where in long:
            print(f"    {n:3d}  {where}")


if __name__ == "__main__":
    main()
