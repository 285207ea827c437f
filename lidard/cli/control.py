"""``lidarctl control acquire|release|status``: the daemon's control lock (docs/api.md).

``acquire`` prints the lease; export it as ``LIDARD_LEASE`` (or pass ``--lease``) so that mutating
commands (scan, linearize, selftest, faults ack) carry it.
"""

from __future__ import annotations

from . import output
from .base import CliError
from .client import client, daemon_opts


def add_parser(sub) -> None:
    sp = sub.add_parser("control", help="take, release or show the daemon's control lock")
    daemon_opts(sp)
    sp.add_argument("action", choices=["acquire", "release", "status"], help="what to do with the lock")
    sp.add_argument("--client", default=None,
                    help="name shown to other clients, up to 64 characters (default user@host)")
    sp.set_defaults(fn=cmd_control)


def cmd_control(args) -> int:
    with client(args) as c:
        if args.action == "acquire":
            import getpass
            import socket
            name = args.client or f"{getpass.getuser()}@{socket.gethostname()}"
            out = c.request("POST", "/control", json={"client": name[:64]}).json()
        elif args.action == "release":
            if not c.lease:
                raise CliError("control release: give the lease with --lease or LIDARD_LEASE")
            out = c.request("DELETE", "/control").json()
        else:
            out = c.get_json("/control")
    if args.json:
        output.emit_json(out)
    elif args.action == "acquire":
        print(f"control lock held by {out['holder']} for {out['ttl_s']:g} s after each use; "
              f"export LIDARD_LEASE={out['lease']}")
    elif out.get("held"):
        print(f"control lock held by {out['holder']} (lapses in {out['expires_in_s']:.0f} s unless used)")
    else:
        print("control lock free" + (" (released)" if args.action == "release" else ""))
    return 0
