"""Count the constants and rules between the per-ramp CFAR and a point, at any commit (read through git).

    python benchmarks/rules_count.py [REV ...] [--list]      (default: 58d6e69 5aa4b52^ HEAD)

The modules counted are those that turn detections into points: everything under ``lidard/dsp/ranging``,
and ``threeseg``, ``cwhold``, ``gate``, ``iqbalance``, ``cfar_post``, ``velocity``, ``frame`` and
``resolve`` (the single-tone residual rule, gone since 63ecaca) of ``lidard/dsp``, wherever they sit
under ``lidard/dsp`` (the sub-package moves keep their names). Per module, from its syntax tree
(Python's ``ast``, no import):

* **constants**: module-level assignments of a number (a literal, a signed literal or arithmetic of
  literals) or of a tuple of numbers;
* **defaults**: numeric default values of function parameters (a tuning number that lives in a
  signature; ``None``, booleans and strings are not counted);
* **branches**: ``if`` / ``elif`` statements, conditional expressions (``a if c else b``) and
  ``np.where`` / ``np.select`` calls (the vectorised ``if``), without the input checks (an ``if`` whose
  body only raises: they reject bad input, they decide nothing about a point).

``--list`` prints every constant with its value and the per-function branch counts.
"""

from __future__ import annotations

import argparse
import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODULES = ("threeseg", "cwhold", "gate", "iqbalance", "cfar_post", "_post", "velocity", "frame", "resolve")
# Moved into lidard/dsp/ranging by the package reorganisation but not part of the count before it (the
# per-ramp estimator and the bound it is checked against): left out so that every revision counts the
# same modules. ``_post`` is ``cfar_post`` under its new name in lidard/dsp/detect.
NOT_COUNTED_IN_RANGING = ("estimators", "crlb")
DEFAULT_REVS = ("58d6e69", "5aa4b52^", "HEAD")


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True, text=True).stdout


def files_at(rev: str) -> list[str]:
    """The counted modules' paths at ``rev``."""
    out = []
    for path in _git("ls-tree", "-r", "--name-only", rev, "lidard/dsp").split():
        p = Path(path)
        if p.suffix != ".py" or p.name == "__init__.py":
            continue
        if ("ranging" in p.parts and p.stem not in NOT_COUNTED_IN_RANGING) or p.stem in MODULES:
            out.append(path)
    return sorted(out)


def _numeric(node: ast.AST) -> bool:
    if isinstance(node, ast.Constant):
        return isinstance(node.value, (int, float)) and not isinstance(node.value, bool)
    if isinstance(node, ast.UnaryOp):
        return _numeric(node.operand)
    if isinstance(node, ast.BinOp):
        return _numeric(node.left) and _numeric(node.right)
    if isinstance(node, ast.Tuple):
        return bool(node.elts) and all(_numeric(e) for e in node.elts)
    return False


def constants(tree: ast.Module) -> list[tuple[str, str]]:
    out = []
    for node in tree.body:
        if isinstance(node, ast.Assign) and _numeric(node.value):
            for t in node.targets:
                if isinstance(t, ast.Name):
                    out.append((t.id, ast.unparse(node.value)))
        elif isinstance(node, ast.AnnAssign) and node.value is not None and _numeric(node.value) \
                and isinstance(node.target, ast.Name):
            out.append((node.target.id, ast.unparse(node.value)))
    return out


def _only_raises(body: list[ast.stmt]) -> bool:
    return all(isinstance(s, ast.Raise) for s in body)


def numeric_defaults(tree: ast.Module) -> list[tuple[str, str]]:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            args = node.args
            pos = args.posonlyargs + args.args
            pairs = list(zip(pos[len(pos) - len(args.defaults):], args.defaults))
            pairs += [(a, d) for a, d in zip(args.kwonlyargs, args.kw_defaults) if d is not None]
            out += [(f"{node.name}({a.arg})", ast.unparse(d)) for a, d in pairs if _numeric(d)]
    return out


class _Branches(ast.NodeVisitor):
    def __init__(self) -> None:
        self.by_function: dict[str, int] = {}
        self.checks = 0
        self._where = ["<module>"]

    def _count(self, k: int = 1) -> None:
        name = self._where[-1]
        self.by_function[name] = self.by_function.get(name, 0) + k

    def visit_FunctionDef(self, node: ast.FunctionDef) -> None:
        self._where.append(node.name)
        self.generic_visit(node)
        self._where.pop()

    visit_AsyncFunctionDef = visit_FunctionDef  # type: ignore[assignment]

    def visit_If(self, node: ast.If) -> None:
        if _only_raises(node.body) and not node.orelse:
            self.checks += 1
        else:
            self._count()
        self.generic_visit(node)

    def visit_IfExp(self, node: ast.IfExp) -> None:
        self._count()
        self.generic_visit(node)

    def visit_Call(self, node: ast.Call) -> None:
        f = node.func
        if isinstance(f, ast.Attribute) and f.attr in ("where", "select") and isinstance(f.value, ast.Name) \
                and f.value.id in ("np", "numpy") and (f.attr == "select" or len(node.args) == 3):
            self._count()
        self.generic_visit(node)


def count(rev: str) -> dict:
    mods = {}
    for path in files_at(rev):
        src = _git("show", f"{rev}:{path}")
        tree = ast.parse(src)
        v = _Branches()
        v.visit(tree)
        mods[path] = {"lines": src.count("\n"), "constants": constants(tree), "defaults": numeric_defaults(tree),
                      "branches": sum(v.by_function.values()), "by_function": v.by_function, "checks": v.checks}
    return {"rev": rev, "commit": _git("rev-parse", "--short", rev).strip(), "modules": mods,
            "constants": sum(len(m["constants"]) for m in mods.values()),
            "defaults": sum(len(m["defaults"]) for m in mods.values()),
            "branches": sum(m["branches"] for m in mods.values()),
            "lines": sum(m["lines"] for m in mods.values())}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("revs", nargs="*", default=list(DEFAULT_REVS))
    ap.add_argument("--list", action="store_true", help="every constant and the branches per function")
    a = ap.parse_args(argv)
    results = [count(r) for r in a.revs]
    print("| module | " + " | ".join(f"{r['rev']} ({r['commit']}): constants / defaults / branches / lines" for r in results) + " |")
    print("|---|" + "---|" * len(results))
    names = sorted({Path(p).name if "ranging" not in p else "ranging/" + Path(p).name
                    for r in results for p in r["modules"]})
    for name in names:
        cells = []
        for r in results:
            m = next((v for p, v in r["modules"].items() if p.endswith("/" + name) or p.endswith(name)), None)
            cells.append("-" if m is None else f"{len(m['constants'])} / {len(m['defaults'])} / {m['branches']} / {m['lines']}")
        print(f"| {name} | " + " | ".join(cells) + " |")
    print("| **total** | " + " | ".join(f"**{r['constants']} / {r['defaults']} / {r['branches']} / {r['lines']}**" for r in results) + " |")
    if a.list:
        for r in results:
            print(f"\n### {r['rev']} ({r['commit']})\n")
            for path, m in r["modules"].items():
                consts = ", ".join(f"`{n} = {v}`" for n, v in m["constants"]) or "none"
                defs = ", ".join(f"`{n} = {v}`" for n, v in m["defaults"]) or "none"
                funcs = ", ".join(f"{f} {k}" for f, k in sorted(m["by_function"].items(), key=lambda kv: -kv[1]))
                print(f"- `{path}` ({m['lines']} lines, {m['checks']} input checks not counted): constants {consts}; defaults {defs}; "
                      f"branches by function: {funcs or 'none'}")


if __name__ == "__main__":
    sys.exit(main())
