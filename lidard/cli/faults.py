"""``lidarctl faults ack``: acknowledge the controller's latched safety faults.

A latched fault (an interlock opened, an HV fault) keeps the laser and HV off until a person resets
it, as laser safety expects. ``POST /controller/acknowledge`` clears the latches only when their
cause is gone; the daemon answers 200 ``{"cleared": [...], "by": ..., "at": ...}`` or 409 naming
what is still open, which is printed as one line with a non-zero exit. The control lock is needed,
as for every mutating request.
"""

from __future__ import annotations

from typing import Any

from . import output
from .base import CliError
from .client import check, client, daemon_opts, error_detail


def add_parser(sub) -> None:
    sp = sub.add_parser("faults", help="acknowledge latched safety faults (needs the control lock)")
    daemon_opts(sp)
    sp.add_argument("action", choices=["ack"],
                    help="ack: clear the latched faults whose cause is gone (POST /controller/acknowledge)")
    sp.set_defaults(fn=cmd_faults)


def cmd_faults(args, transport: Any = None) -> int:
    with client(args, transport=transport) as c:
        if not c.lease:
            raise CliError("faults ack: needs the control lock; run `lidarctl control acquire` (it stores the "
                           "lease for later lidarctl calls) or pass the lease with --lease or LIDARD_LEASE")
        r = c.send("POST", "/controller/acknowledge")
        if r.status_code == 409:
            raise CliError(f"faults not acknowledged, still open: {error_detail(r)}")
        check(r)
        out = r.json()
    if args.json:
        output.emit_json(out)
        return 0
    cleared = out.get("cleared") or []
    who = f" by {out['by']}" if out.get("by") else ""
    at = f" at {output.when(out['at'])}" if isinstance(out.get("at"), (int, float)) else (
        f" at {out['at']}" if out.get("at") else "")
    print(f"acknowledged{who}{at}: " + (f"cleared {', '.join(map(str, cleared))}" if cleared
                                         else "no latched faults"))
    return 0
