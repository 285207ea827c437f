"""Hand-measured reports (docs/measured/*.md) survive regeneration: render() appends them verbatim,
in file-name order, so `python -m benchmarks` no longer drops them (issue 18)."""

from pathlib import Path

from benchmarks.report import measured_sections

REPO = Path(__file__).resolve().parents[2]


def test_measured_sections_are_appended_verbatim_in_name_order(tmp_path):
    (tmp_path / "measured").mkdir()
    (tmp_path / "measured" / "20_b.md").write_text("## B\n\nsecond, `python benchmarks/b.py`\n")
    (tmp_path / "measured" / "10_a.md").write_text("## A\n\nfirst\n")
    text = measured_sections(tmp_path)
    assert text.index("## A") < text.index("## B")
    assert "second, `python benchmarks/b.py`" in text
    assert measured_sections(tmp_path / "nowhere") == ""


def test_every_shipped_measured_section_names_its_command():
    files = sorted((REPO / "docs" / "measured").glob("*.md"))
    assert files
    for f in files:
        text = f.read_text()
        assert text.startswith("## "), f
        assert "python " in text and "benchmarks/" in text, f"{f.name}: no command to reproduce it"
