"""Production code says why, not which ticket: no module of lidard/, drivers/ or sim_devices/ refers to
an issue of the tracker ("issue 13", "issues 6 and 11", "#13" after "issue"). A reader without the
tracker learns nothing from one; the design reason goes in its place and the history in docs/."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRODUCTION = ("lidard", "drivers", "sim_devices")
TRACKER_REF = re.compile(r"\bissues? #?\d+", re.IGNORECASE)
TEXT_SUFFIXES = {".py", ".md", ".toml", ".txt", ".html", ".js", ".css", ".json"}


def tracker_refs(text: str) -> list[str]:
    """The issue references in ``text``, as written."""
    return [m.group(0) for m in TRACKER_REF.finditer(text)]


def test_the_pattern_finds_the_forms_that_were_used():
    text = "fast (issue 18), rooms (Issue 12): ... (issues 6 and 11); see issue #4; an issue of 3 parts"
    assert tracker_refs(text) == ["issue 18", "Issue 12", "issues 6", "issue #4"]


def test_no_production_file_refers_to_an_issue_number():
    found = []
    for top in PRODUCTION:
        for path in sorted((ROOT / top).rglob("*")):
            if path.suffix not in TEXT_SUFFIXES or "vendor" in path.parts or not path.is_file():
                continue
            for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
                if tracker_refs(line):
                    found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not found, "tracker references in production code (write the design reason):\n" + "\n".join(found)
