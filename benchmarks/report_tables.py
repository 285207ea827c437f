"""Building blocks of the benchmark report (``benchmarks/report.py``): what a section returns, how
a missing provider is reported, and the markdown/PNG formatting every section shares.

A section is a function ``(quick, img_dir, log) -> Section`` (``benchmarks/report_sections/``); it
fills the markdown, the figures as data (the report's JSON) and its headline rows (what, measured,
target). :func:`need` fetches a function another benchmark module must supply, or raises
:class:`SectionUnavailable` naming it, so a missing module is reported instead of crashing the run.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from collections.abc import Callable

import numpy as np


class SectionUnavailable(RuntimeError):
    """A section's provider (a function another module must supply) is not there."""


@dataclass
class Section:
    key: str
    title: str
    markdown: str = ""
    data: dict = field(default_factory=dict)
    headline: list[tuple[str, str, str]] = field(default_factory=list)   # (what, measured, target)
    seconds: float = 0.0
    rss_mb: float = 0.0          # the report process's RSS high-water mark after this section
    error: str | None = None


def need(module: str, name: str) -> Callable:
    """benchmarks.<module>.<name>, or a SectionUnavailable that says what is missing."""
    try:
        mod = importlib.import_module(f"benchmarks.{module}")
    except ImportError as exc:
        raise SectionUnavailable(f"benchmarks/{module}.py cannot be imported: {exc}") from None
    fn = getattr(mod, name, None)
    if not callable(fn):
        raise SectionUnavailable(f"benchmarks/{module}.py has no function {name}() yet "
                                 f"(the stated interface of issue 7)")
    return fn


def fmt(x: Any, spec: str = ".3g") -> str:
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return f"{int(x):,}"
    if isinstance(x, (float, np.floating)):
        if not math.isfinite(float(x)):
            return "n/a"
        return format(float(x), spec)
    return str(x)


def table(header: list[str], rows: list[list[Any]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        out.append("| " + " | ".join(c if isinstance(c, str) else fmt(c) for c in r) + " |")
    return "\n".join(out) + "\n"


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, img_dir: Path, name: str) -> str:
    img_dir.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(img_dir / name, dpi=100)
    _plt().close(fig)
    return f"img/{name}"
