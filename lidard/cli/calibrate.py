"""``lidarctl calibration``: the range scale/zero, pointing and I/Q calibrations on a running daemon, and the
records of every calibration (REST: lidard.api.routers.geometry).

The steps a lab runs (the reference plate on a rail, perpendicular to the optical axis)::

    lidarctl calibration range add --known-m 0.8     # measures the plate now at z = 0.8 m
    lidarctl calibration range add --known-m 1.1     # ... moved along the rail
    lidarctl calibration range add --known-m 1.4
    lidarctl calibration range fit                   # effective monitor delay + zero offset
    lidarctl calibration pointing --geometry targets.toml
    lidarctl calibration iq                          # I/Q receiver only (adc.iq): any targets in view
    lidarctl calibration list
    lidarctl calibration show ID

Pending plates live in the daemon's store (a restart loses none); a refused fit names the plate to
check (``range drop ID`` removes it). No ``--sim``: an embedded bench lasts one command, the plates
must stay in front of one instrument between the steps.
"""

from __future__ import annotations

import argparse
import json
import tomllib
from typing import Any

from . import output
from .base import CliError
from .client import client, daemon_opts

EPILOG = __doc__.split("::", 1)[1].split("Pending plates", 1)[0]


def add_parser(sub) -> None:
    sp = sub.add_parser("calibration", help="range scale/zero and pointing calibrations; calibration records",
                        epilog="steps:" + EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    csub = sp.add_subparsers(dest="cal_command", required=True, metavar="STEP", help="the step to run")
    rng = csub.add_parser("range", help="plates at known distances -> effective monitor delay and zero offset")
    rsub = rng.add_subparsers(dest="range_command", required=True, metavar="STEP", help="the step to run")
    add = rsub.add_parser("add", help="measure the plate now at z = --known-m (centre pixels)")
    add.add_argument("--known-m", type=float, required=True, help="plate distance from the lens along z, m")
    add.set_defaults(fn=cmd_range_add)
    rsub.add_parser("list", help="the plates measured for the next fit").set_defaults(fn=cmd_range_list)
    drop = rsub.add_parser("drop", help="forget one pending plate (ID) or all of them (--all)")
    drop.add_argument("id", nargs="?", default=None, help="the pending plate's id (`range list`)")
    drop.add_argument("--all", action="store_true", help="forget every pending plate")
    drop.set_defaults(fn=cmd_range_drop)
    rsub.add_parser("fit", help="fit the pending plates; later scans use the result").set_defaults(fn=cmd_range_fit)
    pnt = csub.add_parser("pointing", help="scan targets of known geometry -> pointing model")
    pnt.add_argument("--geometry", required=True, metavar="FILE.toml",
                     help="[[sphere]] centre, radius / [[plane]] point, normal in the sensor frame, metres")
    pnt.set_defaults(fn=cmd_pointing)
    iqp = csub.add_parser("iq", help="the I/Q receiver's gain ratio and phase error, on any targets in view (adc.iq)")
    iqp.add_argument("--max-range-m", type=float, default=2.0,
                     help="range gate of the calibration scan (default 2 m): targets inside it are used")
    iqp.set_defaults(fn=cmd_iq)
    lst = csub.add_parser("list", help="calibration records (range, pointing, iq, linearization), newest first")
    lst.add_argument("--kind", choices=("range", "pointing", "iq", "linearization"), default=None,
                     help="only records of this kind")
    lst.add_argument("--limit", type=int, default=20, help="at most this many records (default 20)")
    lst.set_defaults(fn=cmd_list)
    show = csub.add_parser("show", help="one calibration record: inputs, fitted values, residuals")
    show.add_argument("id", help="the record's id (`calibration list`)")
    show.set_defaults(fn=cmd_show)
    for p in (add, rsub.choices["list"], drop, rsub.choices["fit"], pnt, iqp, lst, show):
        daemon_opts(p)


def _summary(rec: dict[str, Any]) -> str:
    f, r = rec.get("fitted", {}), rec.get("residuals", {})
    if rec["kind"] == "range":
        return (f"delay {f['delay_s'] * 1e9:.4f} ns (nominal {f['nominal_delay_s'] * 1e9:g}, scale {f['scale']:.6f}), "
                f"zero {f['zero_offset_m'] * 1e3:+.3f} mm; chi2 {r['chi2']:.2f}/{r['dof']} dof")
    if rec["kind"] == "pointing":
        return (f"focal x{f['focal_scale']:.5f}, decentre ({f['decentre_px'][0]:+.3f}, {f['decentre_px'][1]:+.3f}) px, "
                f"rotation {f['rotation_rad'] * 57.29578:+.4f} deg, k1 {f['k1']:+.4f}; "
                f"residual {r['rms_mm']:.3f} mm / {r['rms_px']:.3f} px rms")
    if rec["kind"] == "iq":
        return (f"gain x{f['gain']:.5f}, phase {f['phase_deg']:+.3f} deg; image {r['image_rejection_before_db']:.1f} dB "
                f"-> {r['image_rejection_after_db']:.1f} dB after correction ({r['tones']} tones)")
    red = r.get("reduction", {})
    return "linearization: " + ", ".join(f"{k} {v:.3g}x" for k, v in red.items())


def _emit(args, data: Any, text: str) -> int:
    if args.json:
        output.emit_json(data)
    else:
        print(text)
    return 0


def cmd_range_add(args) -> int:
    with client(args) as c:
        m = c.request("POST", "/calibration/range/plates", json={"known_m": args.known_m}, timeout=None).json()
    return _emit(args, m, f"plate {m['id']} at {m['known_m']:g} m: raw range {m['raw_range_m']:.6f} m "
                          f"+- {m['sem_m'] * 1e6:.1f} um over {m['n']} pixels (pixel spread {m['pixel_std_m'] * 1e6:.0f} um)")


def cmd_range_list(args) -> int:
    with client(args) as c:
        ms = c.get_json("/calibration/range/plates")
    rows = [[m["id"], f"{m['known_m']:g}", f"{m['raw_range_m']:.6f}", f"{m['sem_m'] * 1e6:.1f}", m["n"]] for m in ms]
    return _emit(args, ms, output.table(rows, ["ID", "KNOWN (m)", "RAW RANGE (m)", "SEM (um)", "PIXELS"])
                 if rows else "no pending plates")


def cmd_range_drop(args) -> int:
    if (args.id is None) == (not args.all):
        raise CliError("calibration range drop: give one plate ID or --all")
    with client(args) as c:
        path = "/calibration/range/plates" + ("" if args.all else f"/{args.id}")
        n = c.request("DELETE", path).json()["removed"]
    return _emit(args, {"removed": n}, f"removed {n} pending plate(s)")


def cmd_range_fit(args) -> int:
    with client(args) as c:
        rec = c.request("POST", "/calibration/range/fit").json()
    return _emit(args, rec, f"range calibration {rec['id']}: {_summary(rec)}")


def cmd_pointing(args) -> int:
    try:
        with open(args.geometry, "rb") as f:
            geometry = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise CliError(f"--geometry {args.geometry}: cannot read ({exc})") from None
    with client(args) as c:
        rec = c.request("POST", "/calibration/pointing", json={"geometry": geometry}, timeout=None).json()
    return _emit(args, rec, f"pointing calibration {rec['id']}: {_summary(rec)}")


def cmd_iq(args) -> int:
    with client(args) as c:
        rec = c.request("POST", "/calibration/iq", json={"max_range_m": args.max_range_m}, timeout=None).json()
    return _emit(args, rec, f"I/Q calibration {rec['id']}: {_summary(rec)}")


def cmd_list(args) -> int:
    with client(args) as c:
        recs = c.get_json("/calibration/records", params={"limit": args.limit,
                                                         **({"kind": args.kind} if args.kind else {})})
    rows = [[r["id"], r["kind"], output.when(r["created"]),
             "" if r["temperature_c"] is None else f"{r['temperature_c']:.2f}", _summary(r)] for r in recs]
    return _emit(args, recs, output.table(rows, ["ID", "KIND", "CREATED", "TEC (C)", "RESULT"])
                 if rows else "no calibrations stored")


def cmd_show(args) -> int:
    with client(args) as c:
        rec = c.get_json(f"/calibration/records/{args.id}")
    return _emit(args, rec, f"{rec['kind']} calibration {rec['id']}: {_summary(rec)}\n"
                            + json.dumps({k: rec[k] for k in ("inputs", "fitted", "residuals")}, indent=2))
