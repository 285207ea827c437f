"""``lidarctl scans list|show|fetch``: the daemon's stored scans (GET /scans, /scans/{id}, points)."""

from __future__ import annotations

from typing import Any

from . import base, output
from .base import CliError
from ..outputs import FORMATS
from .client import client, daemon_opts


def add_parser(sub) -> None:
    sp = sub.add_parser("scans", help="list, show or fetch stored scans")
    daemon_opts(sp)
    sp.add_argument("action", choices=["list", "show", "fetch"], help="what to do")
    sp.add_argument("id", nargs="?", help="scan ID (show, fetch)")
    sp.add_argument("--format", choices=list(FORMATS), default=None,
                    help="fetch: file format (default: from the --out extension)")
    sp.add_argument("--out", default=None, metavar="FILE", help="fetch: write the point cloud here")
    sp.set_defaults(fn=cmd_scans)


def _request_text(req: dict[str, Any]) -> str:
    parts = [str(req.get("pattern", "-"))]
    for k in ("rows", "cols"):
        if req.get(k) is not None:
            a, b = req[k]
            parts.append(f"{k} {a}:{b}")
    if req.get("pixels") is not None:
        parts.append(f"{len(req['pixels'])} pixels")
    if req.get("averages") is not None:
        parts.append(f"{req['averages']} averages")
    if req.get("max_range_m") is not None:
        parts.append(f"max range {req['max_range_m']:g} m")
    if req.get("max_speed_mps") is not None:
        parts.append(f"max speed {req['max_speed_mps']:g} m/s")
    if req.get("phase_noise_compensation") is not None:
        parts.append(f"phase-noise compensation {req['phase_noise_compensation']}")
    return ", ".join(parts)


def _calibrated_text(s: dict[str, Any]) -> str | None:
    """``range <id>, pointing NO, linearization <id>`` (uncalibrated is said)."""
    cal = s.get("calibrated")
    if not cal:
        return None
    ids = {"range": s.get("range_calibration_id"), "pointing": s.get("pointing_calibration_id"),
           "linearization": s.get("calibration_id"), "iq": s.get("iq_calibration_id")}
    kinds = ("range", "pointing", "linearization") + (("iq",) if "iq" in cal else ())   # iq: adc.iq only
    return ", ".join(f"{k} {ids[k] or 'yes' if cal.get(k) else 'NO'}" for k in kinds)


def show_text(s: dict[str, Any]) -> str:
    """GET /scans/{id} as a key/value table; a pixel list is counted, not printed."""
    t, n = s["timing"], s["counts"]
    planned = n["pixels_planned"]
    return output.key_values([
        ("id", s["id"]),
        ("state", s["state"] + (" (partial)" if s["partial"] else "")),
        ("stage", s.get("stage")),
        ("progress", f"{s['progress'] * 100:.1f} %"),
        ("error", s.get("error")),
        ("request", _request_text(s.get("request") or {})),
        ("points", n["points"]),
        ("pixels", f"{n['pixels_scanned']}/{planned}"
                   + (f" ({n['pixels_scanned'] / planned * 100:.1f} % coverage)" if planned else "")),
        ("created", output.when(t.get("created"))),
        ("started", output.when(t.get("started"))),
        ("finished", output.when(t.get("finished"))),
        ("hardware time", output.seconds(t.get("hardware_time_s"))),
        ("wall time", output.seconds(t.get("wall_time_s"))),
        ("files", ", ".join(s.get("formats") or []) or None),
        ("calibration", s.get("calibration_id")),
        ("calibrated", _calibrated_text(s)),
        ("uncalibrated because", s.get("uncalibrated_reason")),
        ("raw capture", f"{s['raw_bytes'] / 1e6:.1f} MB" if s.get("raw_bytes") else None),
        ("reprocessed from", s.get("reprocessed_from")),
    ])


def cmd_scans(args) -> int:
    with client(args) as c:
        if args.action == "list":
            data = c.get_json("/scans")
            if args.json:
                output.emit_json(data)
                return 0
            rows = [[s["id"], s["state"] + (" (partial)" if s["partial"] else ""), f"{s['progress'] * 100:.1f} %",
                     s["counts"]["points"], s["request"].get("pattern", "")] for s in data["scans"]]
            print(output.table(rows, ["ID", "STATE", "PROGRESS", "POINTS", "PATTERN"]))
        elif args.action == "show":
            if not args.id:
                raise CliError("scans show: give a scan ID")
            rec = c.get_json(f"/scans/{args.id}")
            output.emit_json(rec) if args.json else print(show_text(rec))
        else:
            _fetch(c, args)
    return 0


def _fetch(c, args) -> None:
    from ..outputs import format_of
    if not args.id or not args.out:
        raise CliError("scans fetch: give a scan ID and --out FILE")
    fmt = args.format or format_of(args.out)
    base.check_out(args.out)
    r = c.request("GET", f"/scans/{args.id}/points", params={"format": fmt})
    base.write_bytes_atomic(args.out, r.content)
    if args.json:
        output.emit_json({"id": args.id, "out": str(args.out), "bytes": len(r.content)})
    else:
        print(f"wrote {args.out} ({len(r.content)} bytes)")
