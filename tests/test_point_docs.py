"""The point-field tables of README.md and docs/api.md are generated from lidard.outputs.schema and fail
here when they drift (regenerate with ``python tools/gen_point_docs.py``)."""

import importlib.util
from pathlib import Path

import pytest

from lidard.outputs.schema import POINT_FIELDS

ROOT = Path(__file__).resolve().parent.parent


def _gen():
    spec = importlib.util.spec_from_file_location("gen_point_docs", ROOT / "tools" / "gen_point_docs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("rel, names", [("README.md", {"fields"}), ("docs/api.md", {"formats", "registry"})])
def test_docs_tables_are_the_generated_ones(rel, names):
    gen = _gen()
    text = (ROOT / rel).read_text(encoding="utf-8")
    assert set(gen.blocks(text)) == names
    assert gen.render(text) == text, f"{rel} drifted from lidard/outputs/schema.py: python tools/gen_point_docs.py"


def test_every_field_is_in_the_tables_with_its_unit():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    api = (ROOT / "docs/api.md").read_text(encoding="utf-8")
    for f in POINT_FIELDS:
        assert f"| `{f.name}` |" in readme and f"| `{f.name}` |" in api, f.name
        row = next(ln for ln in readme.splitlines() if ln.startswith(f"| `{f.name}` |"))
        assert f"| {f.unit or '-'} |" in row, f.name


def test_a_drifted_table_is_caught_and_rewritten():
    gen = _gen()
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    drifted = text.replace("| `flags` |", "| `flagz` |")
    assert gen.render(drifted) != drifted and gen.render(drifted) == text


def test_the_flags_field_names_every_flag_bit_the_dsp_sets():
    from lidard.dsp.detect.gate import PointFlag
    desc = next(f.meaning for f in POINT_FIELDS if f.name == "flags")
    for flag in PointFlag:
        assert f"{int(flag)} {flag.name.lower().replace('_', ' ')}" in desc, flag
