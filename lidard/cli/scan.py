"""``lidarctl scan``: one scan on a running daemon, or with ``--sim`` on an embedded simulated bench.

The request is checked with the daemon's own schema (lidard.api.schemas.ScanCreate) and the scan
planner (lidard.instrument.plan.plan: bonded rows, array bounds) before any bench starts or any request is sent,
so ``--averages 0`` is refused here with the words the daemon would use. Ctrl-C, SIGTERM and SIGHUP
cancel the scan, keep the points measured so far (written to ``--out`` with a partial sidecar whose
``stop_reason`` names the signal) and exit 128 + the signal's number (130, 143, 129; lidard.cli.base).
When the daemon itself shuts down mid-scan, the scan's final record (state ``interrupted``) is printed
from its last event even if the daemon is gone before the record could be fetched again.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from . import base, output
from .base import CliError, Interrupted, describe_signal, signal_of
from .client import Unreachable, client, daemon_opts, refuse_sim_only
from .progress import MODES, Progress

PATTERNS = ("raster", "serpentine", "roi", "pixels", "adaptive")

EPILOG = """\
patterns (--pattern):
  raster      row by row, every wire-bonded row left to right (the frame of Fig. 4-35)
  serpentine  like raster, every other row right to left: the column switch only steps to a neighbour
  roi         raster inside --rows/--cols (implied when --rows or --cols is given alone)
  pixels      only the listed pixels, in order: --pixels R,C [R,C ...] or --pixels-file FILE
  adaptive    a coarse pass (every 4th row and column), then a dense re-scan where it saw returns
  Unbonded rows (one in four on the 128x128 chip) are skipped by raster/serpentine/roi and refused in
  a pixel list.

examples:
  # simulated bench, no daemon: the letters scene, written as PLY plus FILE.ply.json sidecar
  lidarctl scan --sim --scene config/scenes/cal_letters.toml --out /tmp/cal.ply
  # on a running daemon (take the control lock first): four pixels, 4 averages, 5 m range gate
  lidarctl control acquire          # stores the lease for the next lidarctl calls to this daemon
  lidarctl scan --pixels 0,0 0,1 4,10 8,20 --averages 4 --max-range 5 --out px.las
"""


def add_parser(sub) -> None:
    sp = sub.add_parser("scan", help="run a scan (on the daemon, or --sim in process)",
                        description="Run one scan and optionally write its point cloud.",
                        epilog=EPILOG, formatter_class=base.HelpFormatter)
    daemon_opts(sp, sim=True)
    sp.add_argument("--profile", default=None, help="only with --sim: scanner profile (fpsa20, fpsa128, ...) "
                                                    "instead of the configuration's")
    sp.add_argument("--scene", default=None, metavar="FILE.toml",
                    help="only with --sim: scene TOML (default: the configuration's sim.scene)")
    sp.add_argument("--uncalibrated", action="store_true", default=None,
                    help="only with --sim: neither run the simulated bench's factory range/pointing calibration "
                         "(before the first scan of a bench with none of its set-up) nor take it from the user's "
                         "cache; records kept in --data-dir still apply")
    sp.add_argument("--pattern", choices=PATTERNS, default=None,
                    help="scan pattern, see below (default: the daemon's/config's scan.pattern)")
    sp.add_argument("--rows", default=None, metavar="A:B", help="FPSA rows A <= row < B (pixel indices)")
    sp.add_argument("--cols", default=None, metavar="A:B", help="FPSA columns A <= col < B (pixel indices)")
    sp.add_argument("--pixels", nargs="+", default=None, metavar="R,C",
                    help="pattern 'pixels': FPSA pixels as row,col indices (implies --pattern pixels)")
    sp.add_argument("--pixels-file", default=None, metavar="FILE",
                    help="pattern 'pixels': a file of row,col indices, one pixel a line ('#' comments) "
                         "or a JSON list of [row, col]")
    sp.add_argument("--averages", type=int, default=None, metavar="N",
                    help="chirps averaged per pixel, 1..100 (count; default: scan.averages)")
    sp.add_argument("--max-range", type=float, default=None, metavar="M",
                    help="range gate in metres, > 0 (default: scan.max_range_m); points are reported up to 5 %% past it, none beyond")
    sp.add_argument("--max-speed", type=float, default=None, metavar="M",
                    help="fastest radial speed to measure, m/s, > 0: sizes the digitizer's Doppler band "
                         "(default: scan.max_speed_mps)")
    sp.add_argument("--phase-noise", choices=["auto", "on", "off"], default=None,
                    help="laser phase-noise compensation from the monitor MZI (default: scan.* of the config)")
    sp.add_argument("--record-raw", action="store_true",
                    help="also keep the digitizer's raw segments (Zarr, scans/<id>/raw.zarr in the data "
                         "directory) for `lidarctl reprocess` and `lidarctl spectrum`")
    sp.add_argument("--out", default=None, metavar="FILE",
                    help="write the point cloud here (.ply, .las, .npz, .pcd, .mcap for Foxglove/Lichtblick or "
                         ".ros2.mcap for ROS 2) and its FILE.json sidecar; the directory must exist")
    sp.add_argument("--progress", choices=MODES, default="auto",
                    help="stderr progress: bar with ETA on a terminal, one line per 10 %% otherwise (auto), "
                         "JSON lines, or none")
    sp.set_defaults(fn=cmd_scan)


def _range(text: str, name: str) -> list[int]:
    try:
        a, b = (int(x) for x in text.split(":"))
    except ValueError:
        raise CliError(f"--{name}: expected A:B (first:stop), got {text!r}") from None
    return [a, b]


def _pixel(text: str, where: str) -> list[int]:
    parts = text.replace(",", " ").split()
    try:
        r, c = (int(x) for x in parts)
    except ValueError:
        raise CliError(f"{where}: expected ROW,COL (two integers), got {text!r}") from None
    return [r, c]


def read_pixels_file(path: str) -> list[list[int]]:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise CliError(f"--pixels-file {path}: {exc.strerror or exc}") from None
    if text.lstrip().startswith("["):
        try:
            data = json.loads(text)
            return [[int(r), int(c)] for r, c in data]
        except (ValueError, TypeError) as exc:
            raise CliError(f"--pixels-file {path}: not a JSON list of [row, col] ({exc})") from None
    pixels = []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if line:
            pixels.append(_pixel(line, f"--pixels-file {path} line {n}"))
    if not pixels:
        raise CliError(f"--pixels-file {path}: no pixels in the file")
    return pixels


def request_body(args, fmt: str) -> dict[str, Any]:
    """The POST /scans body for the given flags, checked as the daemon checks it."""
    from ..api.schemas import check_scan_body
    body: dict[str, Any] = {"formats": [fmt]}
    if args.pixels is not None and args.pixels_file is not None:
        raise CliError("give --pixels or --pixels-file, not both")
    pixels = ([_pixel(p, "--pixels") for p in args.pixels] if args.pixels is not None
              else read_pixels_file(args.pixels_file) if args.pixels_file is not None else None)
    if args.pattern is not None:
        body["pattern"] = args.pattern
    elif pixels is not None:
        body["pattern"] = "pixels"
    elif args.rows or args.cols:
        body["pattern"] = "roi"
    if pixels is not None:
        body["pixels"] = pixels
    if args.rows is not None:
        body["rows"] = _range(args.rows, "rows")
    if args.cols is not None:
        body["cols"] = _range(args.cols, "cols")
    if args.averages is not None:
        body["averages"] = args.averages
    if args.max_range is not None:
        body["max_range_m"] = args.max_range
    if args.max_speed is not None:
        body["max_speed_mps"] = args.max_speed
    if args.phase_noise is not None:
        body["phase_noise_compensation"] = args.phase_noise
    if args.record_raw:
        body["record_raw"] = True
    try:
        check_scan_body(body)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    return body


def sim_request(body: dict[str, Any], cfg):
    """The instrument request of ``--sim``: the flags left out take the configuration's [scan]
    defaults, as the daemon fills them (ScanCreate.to_request)."""
    from ..api.schemas import check_scan_body
    return check_scan_body(body).to_request(cfg.scan)


def check_plan(req, optics) -> None:
    """The planner's check (bonded rows, array bounds) on this device, before the bench starts."""
    from ..instrument.plan import ScanPlanError, plan
    try:
        plan(req, optics)
    except ScanPlanError as exc:
        raise CliError(str(exc)) from None


def summary(rec: dict[str, Any], out: str | None, simulated: bool | None) -> dict[str, Any]:
    hw, wall = rec.get("hardware_time_s"), rec.get("wall_time_s")
    planned = rec.get("pixels_planned") or 0
    return {
        "id": rec["id"], "state": rec["state"], "partial": bool(rec.get("partial")),
        "points": rec.get("points", 0), "out": out, "error": rec.get("error"),
        "hardware_time_s": hw, "wall_time_s": wall,
        "realtime_factor": (hw / wall) if hw is not None and wall else None,
        "coverage": (rec.get("pixels_scanned", 0) / planned) if planned else 0.0,
        "simulated": simulated,
    }


def cmd_scan(args) -> int:
    from ..outputs import format_of
    refuse_sim_only(args, "--scene", "--profile", "--config", "--data-dir", "--no-cal-cache", "--uncalibrated")
    fmt = format_of(args.out) if args.out else "ply"
    base.check_out(args.out)
    body = request_body(args, fmt)
    bar = Progress(args.progress)
    interrupted: list[int | None] = [None]   # the signal number that stopped the scan
    try:
        s = _scan_sim(args, body, bar, interrupted) if args.sim else _scan_daemon(args, body, bar, interrupted)
    finally:
        bar.close()
    warn_uncalibrated(s.get("calibrated"), s.get("uncalibrated_reason"))
    if args.json:
        output.emit_json({**s, "interrupted": interrupted[0] is not None})
    else:
        print(f"scan {s['id']}: {s['state']}{' (partial)' if s['partial'] else ''}, "
              f"{s['points']} points, coverage {s['coverage'] * 100:.1f} %"
              + (f", written to {s['out']}" if s["out"] else ""))
    if interrupted[0] is not None:
        raise Interrupted(f"scan {s['id']} {s['state']}, {s['points']} points kept"
                          + (f" in {s['out']}" if s["out"] else ""), signum=interrupted[0])
    if s["state"] not in ("done", "cancelled"):
        raise CliError(f"scan {s['id']} {s['state']}: {s.get('error') or 'no detail'}")
    return 0


def warn_uncalibrated(calibrated: dict[str, bool] | None, reason: str | None = None) -> None:
    """One stderr line when the scan had no range or pointing calibration (uncalibrated is said, never hidden), with the
    reason stored calibrations were left out (made on another set-up) when there was one."""
    missing = [k for k in ("range", "pointing") if calibrated is not None and not calibrated.get(k)]
    if missing:
        print(f"lidarctl: warning: uncalibrated {' and '.join(missing)}: ranges and x, y, z carry the scanner's "
              "unmeasured range scale/zero and pointing errors (see `lidarctl calibrate --help`)"
              + (f"; {reason}" if reason else ""), file=sys.stderr)
    if calibrated is not None and calibrated.get("iq") is False:
        print("lidarctl: warning: uncalibrated I/Q receiver: the hybrid's image of every return is only "
              "suppressed to its own imbalance (see `lidarctl calibration iq`)", file=sys.stderr)


def _flat(rec: dict[str, Any]) -> dict[str, Any]:
    """A record as GET /scans/{id} answers it, in the keys of :func:`summary`."""
    return {"id": rec["id"], "state": rec["state"], "partial": rec["partial"], **rec["counts"],
            "hardware_time_s": rec["timing"]["hardware_time_s"], "wall_time_s": rec["timing"]["wall_time_s"]}


def _scan_daemon(args, body: dict[str, Any], bar, interrupted: list[int | None]) -> dict[str, Any]:
    from ..outputs import sidecar_path
    with client(args) as c:
        sid = c.request("POST", "/scans", json=body).json()["id"]
        try:
            end = c.follow(sid, bar)
        except KeyboardInterrupt as exc:
            interrupted[0] = signal_of(exc)
            c.request("DELETE", f"/scans/{sid}")
            end = c.follow(sid, bar)
        out = None
        try:
            rec = c.get_json(f"/scans/{sid}")
            fmt = body["formats"][0]
            if args.out and fmt in rec["formats"]:
                points = c.request("GET", f"/scans/{sid}/points", params={"format": fmt}).content
                side = c.request("GET", f"/scans/{sid}/sidecar", params={"format": fmt}).content
                base.write_bytes_atomic(args.out, points)
                base.write_bytes_atomic(sidecar_path(args.out), side)
                out = str(args.out)
            simulated = bool(c.get_json("/health").get("simulated"))
        except Unreachable:
            if not end.get("scan"):
                raise
            # the daemon shut down right after the scan's end: its final record came with that event
            rec, simulated = end["scan"], None
            print(f"lidarctl: lidard stopped after scan {sid} ended; its points stay in the daemon's data "
                  "directory" + (f", {args.out} was not written" if args.out and out is None else ""),
                  file=sys.stderr)
        s = summary(_flat(rec), out, simulated)
        s["error"] = rec.get("error")
        s["calibrated"] = rec.get("calibrated")
        s["uncalibrated_reason"] = rec.get("uncalibrated_reason")
        return s


def _scan_sim(args, body: dict[str, Any], bar, interrupted: list[int | None]) -> dict[str, Any]:
    from ..outputs import sidecar_path
    from .embedded import embedded, resolve, sim_config
    cfg = sim_config(args)
    req = sim_request(body, cfg)
    check_plan(req, cfg.resolved.optics)  # before the bench starts
    with embedded(args, cfg, scene_path=resolve(args.scene), factory=not args.uncalibrated,
                  scan=req) as (worker, store, inst):
        rec = worker.submit_scan(req)
        worker.subscribe(rec.id, bar)
        try:
            final = worker.wait(rec.id)
        except KeyboardInterrupt as exc:
            interrupted[0] = sig = signal_of(exc)
            worker.cancel(rec.id, reason=f"interrupted by {describe_signal(sig)}")
            final = worker.wait(rec.id)
        out = None
        fmt = body["formats"][0]
        if args.out and fmt in final.files:
            src = store.data_dir / final.files[fmt]
            base.copy_atomic(src, args.out)
            base.copy_atomic(sidecar_path(src), sidecar_path(args.out))
            out = str(args.out)
        s = summary(final.to_dict(), out, bool(inst.simulated))
        s["error"] = final.error
        s["calibrated"] = final.calibrated
        s["uncalibrated_reason"] = final.uncalibrated_reason
        return s
