"""How ``lidarctl`` prints: one JSON object with ``--json``, otherwise aligned tables a person reads.

The daemon answers data (GET /devices carries each device's status as a JSON object); :func:`compact`
summarises long sequences ("96 values, 0..126") so that no 96-number list reaches the terminal.
"""

from __future__ import annotations

import datetime as _dt
import json
import sys
from typing import Any
from collections.abc import Iterable, Sequence

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


def when(ts: float | None) -> str:
    """A Unix time as local ISO time to the second."""
    if ts is None:
        return "-"
    return _dt.datetime.fromtimestamp(ts).astimezone().isoformat(timespec="seconds")


def seconds(v: float | None) -> str:
    return "-" if v is None else f"{v:.4g} s"
