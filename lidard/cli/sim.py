"""``lidarctl sim``: steer a daemon's simulated bench (REST: lidard.api.routers.sim) without curl.

    lidarctl sim scene config/scenes/far_wall.toml        # PUT /sim/scene (the file's TOML as sent)
    lidarctl sim faults inject usb_timeout device=digitizer n=2
    lidarctl sim faults list                              # GET /sim/faults
    lidarctl sim faults clear [--kind usb_timeout]        # DELETE /sim/faults

Placing a scene and injecting or clearing a fault change the instrument, so they are mutating requests:
while another client holds the control lock they need its lease (``--lease`` or ``LIDARD_LEASE``, see
``lidarctl control acquire``); the refusal names the holder. With the lock free they pass. On real
hardware the daemon refuses them (409). The fault kinds and their parameters are those of
docs/reliability.md; ``KEY=VALUE`` values are read as JSON when they parse (numbers, true/false),
else as text.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from . import output
from .base import CliError
from .client import Client, client, daemon_opts, error_detail

EPILOG = __doc__.split("\n\n", 2)[1]


def add_parser(sub) -> None:
    sp = sub.add_parser("sim", help="a daemon's simulated bench: place a scene, inject/list/clear faults",
                        epilog="examples:\n" + EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    ssub = sp.add_subparsers(dest="sim_command", required=True, metavar="WHAT", help="scene or faults")
    sc = ssub.add_parser("scene", help="replace the bench's scene by a scene file (config/scenes format)")
    sc.add_argument("file", metavar="FILE.toml", help="scene TOML ([[target]] tables)")
    sc.set_defaults(fn=cmd_scene)
    fl = ssub.add_parser("faults", help="bench faults (docs/reliability.md)")
    fsub = fl.add_subparsers(dest="faults_command", required=True, metavar="ACTION", help="inject, list or clear")
    inj = fsub.add_parser("inject", help="inject one fault: KIND [KEY=VALUE ...]")
    inj.add_argument("kind", help="fault kind, e.g. usb_timeout, tec_offset, interlock_open")
    inj.add_argument("params", nargs="*", metavar="KEY=VALUE", help="the fault's parameters")
    inj.set_defaults(fn=cmd_inject)
    fsub.add_parser("list", help="the faults active now").set_defaults(fn=cmd_list)
    clr = fsub.add_parser("clear", help="clear every fault, or those of --kind")
    clr.add_argument("--kind", default=None, help="only faults of this kind")
    clr.set_defaults(fn=cmd_clear)
    for p in (sc, inj, fsub.choices["list"], clr):
        daemon_opts(p)


def _mutate(c: Client, method: str, path: str, **kw):
    """Send a mutating request; the control lock's refusal (423) becomes one line naming the holder."""
    r = c.send(method, path, **kw)
    if r.status_code == 423:
        try:
            holder = r.json().get("holder")
        except ValueError:
            holder = None
        how = ("the lease you gave is not the held one" if c.lease
               else "pass its lease with --lease or LIDARD_LEASE")
        raise CliError(f"the daemon's control lock is held by {holder or 'another client'}: {how} "
                       "(`lidarctl control status`)")
    if r.status_code >= 400:
        raise CliError(f"lidard answered {r.status_code}: {error_detail(r)}")
    return r.json()


def _value(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return text


def parse_params(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise CliError(f"fault parameter {item!r}: expected KEY=VALUE (e.g. device=digitizer n=2)")
        if key == "kind":
            raise CliError("fault parameter 'kind': give the kind as the first argument, not as kind=...")
        out[key] = _value(value)
    return out


def cmd_scene(args) -> int:
    path = Path(args.file)
    try:
        body = path.read_bytes()
    except OSError as exc:
        raise CliError(f"scene {path}: cannot read ({exc.strerror or exc})") from None
    with client(args) as c:
        out = _mutate(c, "PUT", "/sim/scene", content=body, headers={"Content-Type": "application/toml"})
    if args.json:
        output.emit_json(out)
    else:
        print(f"scene {out['name']!r} placed: {out['targets']} target(s) from {path}")
    return 0


def cmd_inject(args) -> int:
    body = {"kind": args.kind, **parse_params(args.params)}
    with client(args) as c:
        out = _mutate(c, "POST", "/sim/faults", json=body)
    if args.json:
        output.emit_json(out)
    else:
        print(f"fault {out.get('id')} injected: {_describe(out)}")
    return 0


def _describe(f: dict[str, Any]) -> str:
    rest = ", ".join(f"{k}={v}" for k, v in f.items() if k not in ("id", "kind"))
    return f"{f.get('kind')}" + (f" ({rest})" if rest else "")


def cmd_list(args) -> int:
    with client(args) as c:
        faults = c.get_json("/sim/faults")["faults"]
    if args.json:
        output.emit_json({"faults": faults})
        return 0
    rows = [[f.get("id", ""), f.get("kind", ""), ", ".join(f"{k}={v}" for k, v in f.items() if k not in ("id", "kind"))]
            for f in faults]
    print(output.table(rows, ["ID", "KIND", "PARAMETERS"]) if rows else "no faults active")
    return 0


def cmd_clear(args) -> int:
    with client(args) as c:
        out = _mutate(c, "DELETE", "/sim/faults", params={"kind": args.kind} if args.kind else None)
    if args.json:
        output.emit_json(out)
    else:
        print(f"cleared {out['cleared']} fault(s)" + (f" of kind {args.kind}" if args.kind else ""))
    return 0
