"""Typed errors shared by the host side (daemon, CLI, configuration), and the one wording of
pydantic's validation errors.

Each error class says how the REST API answers it (``http_status``; ``retry_after_s`` adds a
``Retry-After`` header): the daemon's one exception handler (:func:`lidard.api.problems.install`)
reads them, so no router maps an error to a status. An error that names no status of its own is
the daemon's state, not the request's fault: 503.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, ClassVar


class LidardError(Exception):
    """Base class for errors lidard reports to users as one clear line."""

    #: the REST API's answer to this error
    http_status: ClassVar[int] = 503
    #: seconds after which a retry may succeed (a ``Retry-After`` header), or None
    retry_after_s: ClassVar[int | None] = None


class ConfigError(LidardError):
    """A configuration, profile or scene file is invalid; the message names file, key and rule."""


class UnknownScan(LidardError):
    """No scan with that id (the job queue, the store's services and the API share it)."""

    http_status = 404


def describe_validation(errors: Iterable[Mapping[str, Any]], *, source: str | None = None,
                        show_input: bool = False) -> str:
    """One line for a list of pydantic validation errors (``ValidationError.errors()``, or the
    daemon's 422 ``errors``): ``averages: Input should be greater than or equal to 1; ...``.

    The one formatter of the configuration's errors, the daemon's 422 bodies and lidarctl's own
    check of a request, so all say the same words. The ``body`` location prefix and pydantic's
    "Value error, " are dropped; an unknown key says so; a message that already names its field
    (the scan planner's "rows: ...") is not prefixed twice. ``source`` (a file) prefixes every
    entry with ``<source>: <location>:``; ``show_input`` adds the offending value.
    """
    parts = []
    for e in errors:
        loc = [str(x) for x in (e.get("loc") or ())]
        if loc and loc[0] == "body":
            loc = loc[1:]
        where = ".".join(loc)
        kind = str(e.get("type", ""))
        msg = str(e.get("msg", "")).removeprefix("Value error, ")
        ctx = e.get("ctx") or {}
        if kind == "extra_forbidden":
            msg = "unknown key"
        elif kind == "literal_error" and "expected" in ctx:
            msg = f"must be {ctx['expected']}"
        got = e.get("input")
        if show_input and got is not None and kind != "missing" and not isinstance(got, dict):
            msg += f" (got {got!r})"
        line = msg if where and msg.startswith(where) else f"{where}: {msg}" if where else msg
        if source is not None:
            line = f"{source}: {line if where else '(top level): ' + msg}"
        parts.append(line)
    return "; ".join(parts)
