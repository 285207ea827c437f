"""The HTTP side of ``lidarctl``: a small httpx client for the daemon's REST API (docs/api.md) and the
options every daemon command shares (``--url``, ``--token``, ``--lease``, ``--json``).

An error answer becomes one :class:`~lidard.cli.base.CliError` line, ``lidard answered <status>:
<detail>``, with 422 lists worded by :func:`lidard.api.schemas.describe_errors` (the same words
lidarctl uses when it refuses a request before sending it).
"""

from __future__ import annotations

import json
import os
from typing import Any
from collections.abc import Callable

from .base import DEFAULT_URL, CliError


class Unreachable(CliError):
    """The daemon did not answer at all (not running, or gone mid-command)."""


class Client:
    def __init__(self, url: str, token: str | None, timeout_s: float = 30.0, lease: str | None = None,
                 transport=None):
        import httpx
        self.url = url.rstrip("/")
        self.lease = lease
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        if lease:  # the control lock (docs/api.md): mutating requests carry the holder's lease
            headers["X-Lidard-Lease"] = lease
        self._http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout_s, transport=transport)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def send(self, method: str, path: str, **kw):
        """The answer, whatever its status (the caller reads error statuses itself)."""
        import httpx
        try:
            return self._http.request(method, path, **kw)
        except httpx.TransportError as exc:
            raise Unreachable(f"cannot reach lidard at {self.url} ({type(exc).__name__}: {exc}); "
                           "is the daemon running?") from None

    def request(self, method: str, path: str, **kw):
        """The answer; an error status raises one CliError line."""
        r = self.send(method, path, **kw)
        check(r)
        return r

    def get_json(self, path: str, **kw) -> Any:
        return self.request("GET", path, **kw).json()

    def follow(self, scan_id: str, on_event: Callable[[dict], None]) -> dict:
        """Read the scan's server-sent events until ``end``; answers that event (with the scan's final
        record under ``scan``: lidard sends it even while it shuts down)."""
        import httpx
        try:
            with self._http.stream("GET", f"/scans/{scan_id}/events", timeout=None) as r:
                if r.status_code >= 400:
                    r.read()
                    check(r)
                event = None
                for line in r.iter_lines():
                    if line.startswith("event: "):
                        event = line[7:]
                    elif line.startswith("data: ") and event:
                        ev = json.loads(line[6:])
                        on_event(ev)
                        if ev.get("event") == "end":
                            return ev
        except httpx.TransportError as exc:
            raise CliError(f"lost the connection to lidard at {self.url} ({exc})") from None
        raise CliError(f"lidard at {self.url} closed the event stream of scan {scan_id} before its end")


def error_detail(r) -> str:
    """The ``detail`` of an error answer as one line."""
    from ..api.schemas import describe_errors
    try:
        detail = r.json().get("detail")
    except (ValueError, AttributeError):
        detail = r.text.strip()
    if isinstance(detail, list):
        detail = describe_errors([d for d in detail if isinstance(d, dict)])
    return str(detail)


def check(r) -> None:
    if r.status_code == 423:
        from . import leases
        raise CliError(f"lidard answered 423: {error_detail(r)}. lidarctl sends the lease given with --lease, "
                       f"else $LIDARD_LEASE, else the one `lidarctl control acquire` stored in {leases.path()} "
                       "for this --url")
    if r.status_code >= 400:
        raise CliError(f"lidard answered {r.status_code}: {error_detail(r)}")


def lease_for(args) -> str | None:
    """The lease a command sends: ``--lease``, else ``$LIDARD_LEASE``, else the user's lease file."""
    from . import leases
    return (getattr(args, "lease", None) or os.environ.get("LIDARD_LEASE")
            or leases.load(args.url) or None)


def client(args, transport=None) -> Client:
    return Client(args.url, args.token or os.environ.get("LIDARD_API_TOKEN"), lease=lease_for(args),
                  transport=transport)


def daemon_opts(sp, sim: bool = False) -> None:
    """The options of every command that talks to a daemon (and, with ``sim``, of the --sim ones)."""
    sp.add_argument("--url", default=os.environ.get("LIDARD_URL", DEFAULT_URL),
                    help=f"daemon URL (default {DEFAULT_URL}, or $LIDARD_URL)")
    sp.add_argument("--token", default=None, help="API token for mutating requests (default $LIDARD_API_TOKEN)")
    sp.add_argument("--lease", default=None, help="control lease sent as X-Lidard-Lease (default $LIDARD_LEASE, "
                                                  "else the one `lidarctl control acquire` stored for --url)")
    sp.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
    if sim:
        sp.add_argument("--sim", action="store_true",
                        help="no daemon: run an embedded simulated bench in this process")
        sp.add_argument("--config", default=None, metavar="FILE.toml",
                        help="configuration TOML (only with --sim; default: the packaged config/sim.toml)")
        sp.add_argument("--data-dir", default=None, metavar="DIR",
                        help="only with --sim: keep the store (calibrations, scans) here instead of a "
                             "temporary directory, so the next run reuses the chirp linearization")
        sp.add_argument("--no-cal-cache", action="store_true", default=None,
                        help="only with --sim and no --data-dir: neither reuse nor keep the chirp "
                             "linearization in the user's cache ($XDG_CACHE_HOME/lidard)")


def refuse_sim_only(args, *flags: str) -> None:
    """``--config``/``--profile``/``--data-dir``/``--scene`` configure the embedded bench; a daemon
    has its own (``lidard --config``), so without ``--sim`` they would be silently ignored."""
    if getattr(args, "sim", False):
        return
    given = [f for f in flags if getattr(args, f.lstrip("-").replace("-", "_"), None) is not None]
    if given:
        raise CliError(f"{', '.join(given)} only appl{'ies' if len(given) == 1 else 'y'} with --sim; "
                       "a daemon uses its own configuration (start it with `lidard --config FILE`)")
