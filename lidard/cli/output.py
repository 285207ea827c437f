"""How ``lidarctl`` prints: one JSON object with ``--json``, otherwise aligned tables a person reads.

The daemon's device entries carry the drivers' identity and status as text (e.g.
``Identity(vendor='lidard-sim', ..., bonded_rows=(0, 1, 2, ...))``); :func:`readable` turns such a
record into ``key value`` pairs and summarises long sequences ("96 values, 0..126") so that no
Python repr or 96-number tuple reaches the terminal.
"""

from __future__ import annotations

import ast
import datetime as _dt
import json
import re
import sys
from typing import Any, Iterable, Sequence

_LONG = 8  # sequences longer than this are summarised, not listed


def json_default(o: Any) -> Any:
    import numpy as np
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def emit_json(obj: Any) -> None:
    sys.stdout.write(json.dumps(obj, default=json_default) + "\n")


def table(rows: Sequence[Sequence[Any]], header: Sequence[str]) -> str:
    """Left-aligned columns, two spaces apart; the last column is not padded."""
    cells = [[str(c) for c in header]] + [["-" if c is None or c == "" else str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r[:-1], widths[:-1])) + "  " + r[-1] for r in cells]
    return "\n".join(line.rstrip() for line in lines)


def key_values(pairs: Iterable[tuple[str, Any]], indent: str = "") -> str:
    pairs = list(pairs)
    width = max((len(k) for k, _ in pairs), default=0)
    return "\n".join(f"{indent}{k.ljust(width)}  {'-' if v is None or v == '' else v}" for k, v in pairs)


def compact(v: Any) -> str:
    """A value for a table cell: short sequences listed, long ones summarised, no reprs."""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple, set, frozenset)):
        items = sorted(v) if isinstance(v, (set, frozenset)) else list(v)
        if not items:
            return "none"
        if len(items) > _LONG:
            nums = [x for x in items if isinstance(x, (int, float)) and not isinstance(x, bool)]
            span = f", {min(nums):g}..{max(nums):g}" if len(nums) == len(items) else ""
            return f"{len(items)} values{span}"
        return ", ".join(compact(x) for x in items)
    if isinstance(v, dict):
        return ", ".join(f"{k}={compact(x)}" for k, x in v.items())
    return str(v)


_ENUM = re.compile(r"<([A-Za-z_][\w]*)\.([A-Za-z_][\w]*): [^>]*>")


def _literal(node: ast.AST) -> Any:
    # frozenset()/set()/tuple() appear in driver reprs; everything else must be a plain literal
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("frozenset", "set", "tuple"):
        return [] if not node.args else list(_literal(node.args[0]))
    return ast.literal_eval(node)


def parse_record(text: str) -> tuple[str, dict[str, Any]] | None:
    """``Name(a=1, b=(1, 2), c=<E.X: 0>)`` -> ``("Name", {"a": 1, "b": [1, 2], "c": "X"})``; None if not one."""
    try:
        node = ast.parse(_ENUM.sub(lambda m: repr(m.group(2)), text.strip()), mode="eval").body
    except SyntaxError:
        return None
    if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and not node.args):
        return None
    try:
        return node.func.id, {kw.arg: _literal(kw.value) for kw in node.keywords if kw.arg}
    except (ValueError, TypeError, SyntaxError):
        return None


def readable(value: Any) -> str:
    """A driver's identity or status for a table: ``key=value`` pairs, long tuples summarised."""
    if value is None:
        return "-"
    if not isinstance(value, str):
        return compact(value)
    text = value.strip()
    if text.startswith("[") or text.startswith("("):
        try:
            return compact(ast.literal_eval(text))
        except (ValueError, SyntaxError):
            return text
    rec = parse_record(text)
    if rec is None:
        return text
    _, fields = rec
    parts = []
    for k, v in fields.items():
        if k in ("faults",) and (v in ("NONE", []) or not v):
            continue  # "no faults" is said by the FAULTS column
        if k == "firmware" and isinstance(v, (list, tuple)):
            v = ".".join(str(x) for x in v)
        if k == "state" and isinstance(v, str):
            parts.insert(0, v.lower())
            continue
        parts.append(f"{k}={compact(v)}")
    return ", ".join(parts) if parts else "-"


def when(ts: float | None) -> str:
    """A Unix time as local ISO time to the second."""
    if ts is None:
        return "-"
    return _dt.datetime.fromtimestamp(ts).astimezone().isoformat(timespec="seconds")


def seconds(v: float | None) -> str:
    return "-" if v is None else f"{v:.4g} s"
