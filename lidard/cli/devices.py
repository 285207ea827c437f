"""``lidarctl status`` (the daemon's health) and ``lidarctl devices`` (one row per instrument)."""

from __future__ import annotations

from . import output
from .client import client, daemon_opts


def add_parsers(sub) -> None:
    sp = sub.add_parser("status", help="daemon health: state, queue, running scan")
    daemon_opts(sp)
    sp.set_defaults(fn=cmd_status)
    sp = sub.add_parser("devices", help="per-device link, identity, state and faults")
    daemon_opts(sp)
    sp.set_defaults(fn=cmd_devices)


def cmd_status(args) -> int:
    with client(args) as c:
        h = c.get_json("/health")
    if args.json:
        output.emit_json(h)
    else:
        print(f"lidard {h['version']} at {args.url}: {h['status']}"
              f"{' (simulated)' if h['simulated'] else ''}; queue {h['queue_length']}, "
              f"running {h['running_scan'] or '-'}")
        if h.get("latched_faults"):
            print(f"controller faults LATCHED: {', '.join(h['latched_faults'])} (interlock "
                  f"{'closed' if h.get('interlock_closed') else 'OPEN'}); laser and HV stay off: remove the "
                  f"cause, then run `lidarctl faults ack`")
        elif h.get("latched_faults") is None and "latched_faults" in h:
            print("controller faults: unknown (controller unreadable; see `lidarctl devices`)")
        if h.get("linearization"):
            print(linearization_line(h["linearization"]))
    return 0


def linearization_line(lin: dict) -> str:
    """The last scan's linearization health check in one line (GET /health ``linearization``)."""
    if lin.get("residual_hz") is None:
        return f"linearization: re-linearized ({lin.get('reason')}), not checked"
    text = (f"linearization: chirp error {lin['residual_hz'] / 1e3:.0f} kHz rms "
            f"(threshold {lin['threshold_hz'] / 1e3:.0f} kHz)")
    return text + (f"; re-linearized: {lin['reason']}" if lin.get("relinearized") else "")


def fields_line(data) -> str:
    """A device's ``status``/``identity_fields`` (GET /devices: data, not text) for a table cell:
    ``key=value`` pairs, long lists summarised, the state word first, faults left to their column."""
    if data is None:
        return "-"
    if not isinstance(data, dict):
        return output.compact(data)
    if "idn" in data and len(data) == 1:
        return str(data["idn"])
    if "error_queue" in data:
        q = data["error_queue"]
        return "ready" if not q else "; ".join(f"error {e['code']}: {e['text']}" for e in q)
    parts: list[str] = []
    for k, v in data.items():
        if k == "faults":
            continue  # said by the FAULTS column
        if k == "firmware" and isinstance(v, list):
            v = ".".join(str(x) for x in v)
        if k == "state" and isinstance(v, str):
            parts.insert(0, v.lower())
            continue
        parts.append(f"{k}={output.compact(v)}")
    return ", ".join(parts) if parts else "-"


def device_rows(devs: list[dict]) -> list[list[str]]:
    rows = []
    for d in devs:
        link = "connected" if d.get("connected") else "DISCONNECTED"
        if d.get("reconnected"):
            link += " (reconnected)"
        if d.get("busy"):
            link += " (busy: last check)"
        faults = output.compact(list(d.get("faults") or [])) if d.get("faults") else "-"
        ident = fields_line(d["identity_fields"]) if d.get("identity_fields") is not None else (d.get("identity") or "-")
        state = fields_line(d["status"]) if d.get("status") is not None else (d.get("state") or "-")
        rows.append([str(d.get("name", "?")), link, ident, state, faults])
    return rows


def cmd_devices(args) -> int:
    with client(args) as c:
        devs = c.get_json("/devices")["devices"]
    if args.json:
        output.emit_json({"devices": devs})
        return 0
    print(output.table(device_rows(devs), ["DEVICE", "LINK", "IDENTITY", "STATE", "FAULTS"]))
    return 0
