"""The DSP's sub-packages show what they offer, and nothing reaches into another package's private rooms.

Each sub-package of :mod:`lidard.dsp` (spectrum, detect, ranging, phasenoise, linearize) lists its
public modules in ``__all__``: every name there is a module of the package that imports, and every
module of the package whose name has no leading underscore is listed (a new room cannot be left out,
a renamed one cannot linger). A module named ``_x`` is private to the package that holds it: no file of
the daemon, drivers, simulator or benchmarks outside that package imports it, by an absolute or a
relative import.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DSP = ROOT / "lidard" / "dsp"
SUBPACKAGES = sorted(p.name for p in DSP.iterdir() if (p / "__init__.py").is_file())


def test_the_dsp_is_split_by_concern_into_few_top_level_rooms():
    assert SUBPACKAGES == ["detect", "linearize", "phasenoise", "ranging", "spectrum"]
    top = sorted(p.name for p in DSP.glob("*.py"))
    assert len(top) <= 12, top


@pytest.mark.parametrize("name", SUBPACKAGES)
def test_all_names_exactly_the_public_modules(name):
    pkg = importlib.import_module(f"lidard.dsp.{name}")
    exported = pkg.__all__
    assert len(exported) == len(set(exported)), exported
    public = sorted(p.stem for p in (DSP / name).glob("*.py") if not p.stem.startswith("_"))
    assert sorted(exported) == public
    for member in exported:
        mod = importlib.import_module(f"lidard.dsp.{name}.{member}")
        assert Path(mod.__file__).parent == DSP / name
    # the private rooms exist and stay out of the list
    private = [p.stem for p in (DSP / name).glob("_*.py") if p.stem != "__init__"]
    assert not set(private) & set(exported)


def _module_of(path: Path) -> list[str]:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return parts[:-1] if parts[-1] == "__init__" else parts


def _imported_modules(path: Path) -> list[tuple[int, list[str]]]:
    """(line, dotted parts) of every module a file imports, relative imports resolved; for ``from P
    import n`` both P and P.n (n may be a module)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = _module_of(path)
    if path.name != "__init__.py":
        package = package[:-1]
    out: list[tuple[int, list[str]]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name.split(".")) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            mod = base + (node.module.split(".") if node.module else [])
            out.append((node.lineno, mod))
            out += [(node.lineno, mod + [a.name]) for a in node.names]
    return out


def _private_owner(parts: list[str]) -> list[str] | None:
    """The package that owns the first private module in a dotted path (None: no private module)."""
    for i, part in enumerate(parts):
        if part.startswith("_") and not part.startswith("__"):
            candidate = ROOT.joinpath(*parts[: i + 1])
            if candidate.with_suffix(".py").is_file() or (candidate / "__init__.py").is_file():
                return parts[:i]
            return None     # a private name inside a module, not a private module
    return None


def test_the_private_resolver_sees_a_private_module_and_not_a_private_name():
    assert _private_owner(["lidard", "dsp", "spectrum", "_kernels"]) == ["lidard", "dsp", "spectrum"]
    assert _private_owner(["lidard", "dsp", "spectrum", "dtft", "_terms_for"]) is None
    assert _private_owner(["lidard", "dsp", "spectrum", "jit"]) is None


def test_no_file_outside_a_package_imports_its_private_modules():
    files = [f for top in ("lidard", "drivers", "sim_devices", "benchmarks") for f in (ROOT / top).rglob("*.py")]
    assert len(files) > 100
    seen_inside = 0
    offences = []
    for f in files:
        here = _module_of(f)
        for line, parts in _imported_modules(f):
            owner = _private_owner(parts)
            if owner is None:
                continue
            if here[: len(owner)] == owner:
                seen_inside += 1
            else:
                offences.append(f"{f.relative_to(ROOT)}:{line} imports {'.'.join(parts)}")
    assert not offences, offences
    # the check saw the DSP's own private imports (jit -> _kernels, cfar -> _post, ilc -> _measure ...)
    assert seen_inside >= 4
