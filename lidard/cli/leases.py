"""Where ``lidarctl control acquire`` keeps the control lease for the same user's later ``lidarctl``
calls, so that the README's next command carries it without an ``export``.

One file per user, ``$XDG_STATE_HOME/lidard/leases.json`` (default ``~/.local/state/lidard``), a JSON
map from daemon URL to lease, readable by its owner only (mode 0600: a lease steers the laser and the
HV supply). A lease is looked up by the URL a command talks to; ``--lease`` and ``$LIDARD_LEASE`` come
first. ``control release`` and ``control handover`` remove the entry; a lease that lapsed on the daemon
is harmless to send (a free lock lets every request through, a lock held by another client answers
423 whatever is sent)."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path


def path() -> Path:
    state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(state) / "lidard" / "leases.json"


def _key(url: str) -> str:
    return url.rstrip("/")


def _read() -> dict[str, str]:
    try:
        data = json.loads(path().read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return {str(k): str(v) for k, v in data.items()} if isinstance(data, dict) else {}


def _write(data: dict[str, str]) -> None:
    p = path()
    p.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    fd, tmp = tempfile.mkstemp(prefix=".leases.", suffix=".tmp", dir=p.parent)   # created 0600
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(data, f, indent=1, sort_keys=True)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load(url: str) -> str | None:
    """The lease stored for the daemon at ``url``, or None."""
    return _read().get(_key(url))


def store(url: str, lease: str) -> Path:
    data = _read()
    data[_key(url)] = lease
    _write(data)
    return path()


def forget(url: str) -> None:
    data = _read()
    if data.pop(_key(url), None) is not None:
        _write(data)
