"""Regenerate the point-field tables of README.md and docs/api.md from lidard.outputs.schema.

``python tools/gen_point_docs.py`` rewrites every block between ``<!-- point-schema:NAME -->`` and
``<!-- /point-schema:NAME -->`` (NAME ``fields``: the schema; ``formats``: each field's type per file
format; ``registry``: the formats themselves, lidard.outputs.registry); ``--check`` only reports the files whose tables drifted (exit status 1).
tests/test_point_docs.py runs the check.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lidard.outputs.registry import registry_table  # noqa: E402
from lidard.outputs.schema import fields_table, formats_table  # noqa: E402

FILES = ("README.md", "docs/api.md")
BLOCKS = {"fields": fields_table, "formats": formats_table, "registry": registry_table}
_BLOCK = re.compile(r"(<!-- point-schema:(\w+) -->\n)(.*?)(<!-- /point-schema:\2 -->)", re.S)


def render(text: str) -> str:
    """``text`` with every point-schema block regenerated (an unknown block name is an error)."""
    def sub(m: re.Match) -> str:
        name = m.group(2)
        if name not in BLOCKS:
            raise SystemExit(f"unknown point-schema block {name!r}; known: {', '.join(BLOCKS)}")
        return f"{m.group(1)}{BLOCKS[name]()}\n{m.group(4)}"
    return _BLOCK.sub(sub, text)


def blocks(text: str) -> list[str]:
    return [m.group(2) for m in _BLOCK.finditer(text)]


def main(argv: list[str]) -> int:
    check = "--check" in argv
    drifted = []
    for rel in FILES:
        path = ROOT / rel
        old = path.read_text(encoding="utf-8")
        new = render(old)
        if new != old:
            drifted.append(rel)
            if not check:
                path.write_text(new, encoding="utf-8")
    if drifted:
        print(("drifted from lidard/outputs/schema.py or registry.py (run python tools/gen_point_docs.py): " if check
               else "rewrote: ") + ", ".join(drifted))
    return 1 if (check and drifted) else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
