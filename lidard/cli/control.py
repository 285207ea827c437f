"""``lidarctl control acquire|release|status|handover``: the daemon's control lock (docs/api.md).

``acquire`` stores the lease in the user's lease file (lidard.cli.leases) for later ``lidarctl``
calls to the same ``--url``, so mutating commands (scan, linearize, selftest, faults ack) carry it
with nothing to export; ``acquire --export`` prints only ``export LIDARD_LEASE=...`` for
``eval "$(lidarctl control acquire --export)"`` (a shell of its own, e.g. on another account).
``release`` gives the lock up, ``handover --client NAME`` gives it to NAME under a fresh lease (printed
for NAME; the old one is void); both forget the stored lease.
"""

from __future__ import annotations

import shlex

from . import leases, output
from .base import CliError
from .client import client, daemon_opts


def add_parser(sub) -> None:
    sp = sub.add_parser("control", help="take, release, hand over or show the daemon's control lock")
    daemon_opts(sp)
    sp.add_argument("action", choices=["acquire", "release", "status", "handover"], help="what to do with the lock")
    sp.add_argument("--client", default=None,
                    help="name shown to other clients, up to 64 characters (default user@host); with "
                         "handover: who gets the lock (required)")
    sp.add_argument("--export", action="store_true",
                    help="acquire/handover: print only `export LIDARD_LEASE=...` (for eval) and store nothing")
    sp.set_defaults(fn=cmd_control)


def cmd_control(args) -> int:
    if args.export and args.action not in ("acquire", "handover"):
        raise CliError(f"--export applies to acquire and handover, not {args.action}")
    if args.action == "handover" and not args.client:
        raise CliError("control handover: name who gets the lock with --client NAME")
    with client(args) as c:
        if args.action == "acquire":
            import getpass
            import socket
            name = args.client or f"{getpass.getuser()}@{socket.gethostname()}"
            out = c.request("POST", "/control", json={"client": name[:64]}).json()
        elif args.action in ("release", "handover"):
            if not c.lease:
                raise CliError(f"control {args.action}: no lease to send; give it with --lease or LIDARD_LEASE, "
                               f"or acquire the lock first (the lease is then stored in {leases.path()})")
            out = (c.request("DELETE", "/control").json() if args.action == "release"
                   else c.request("POST", "/control/handover", json={"client": args.client[:64]}).json())
            leases.forget(args.url)
        else:
            out = c.get_json("/control")
    stored = None
    if args.action == "acquire" and not args.export:
        stored = leases.store(args.url, out["lease"])
    if args.export:
        print(f"export LIDARD_LEASE={shlex.quote(out['lease'])}")
    elif args.json:
        output.emit_json(out)
    elif args.action == "acquire":
        print(f"control lock held by {out['holder']} for {out['ttl_s']:g} s after each use; lease stored in "
              f"{stored} for later lidarctl calls to {args.url} (another shell: export LIDARD_LEASE={out['lease']})")
    elif args.action == "handover":
        print(f"control lock handed over to {out['holder']}; its lease (give it to them): "
              f"export LIDARD_LEASE={out['lease']}")
    elif out.get("held"):
        print(f"control lock held by {out['holder']} (lapses in {out['expires_in_s']:.0f} s unless used)")
    else:
        print("control lock free" + (" (released)" if args.action == "release" else ""))
    return 0
