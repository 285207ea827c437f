"""Names a package imports on first use (PEP 562), so the light entry points (``lidarctl --help``,
the API, the job queue) do not load the heavy modules behind them
(every command's start-up time)."""

from __future__ import annotations

import importlib
from typing import Any
from collections.abc import Callable


def lazy_getattr(package: str, table: dict[str, str], namespace: dict[str, Any]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package``: ``table`` maps a name to the submodule defining it;
    the first access imports it and caches the value in ``namespace`` (the package's globals)."""
    def __getattr__(name: str) -> Any:
        if name in table:
            value = getattr(importlib.import_module(f".{table[name]}", package), name)
            namespace[name] = value
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")
    return __getattr__
