"""``lidarctl reprocess`` and ``lidarctl spectrum``: replay a scan's raw capture (issue 16, items 3-4).

Both work on a scan recorded with ``record_raw`` (``lidarctl scan --record-raw``): through a running
daemon (``POST /scans/{id}/reprocess``, ``GET /scans/{id}/spectrum``), or offline on a data
directory with ``--data-dir DIR`` (no daemon may hold it: the store's lock refuses a second owner).
Reprocessing runs the scan DSP again with the original settings unless overridden, and writes a new
scan linked to the original (``reprocessed_from``).
"""

from __future__ import annotations

from typing import Any

from . import base, output
from .base import CliError
from .client import client, daemon_opts

ESTIMATORS = ("argmax", "parabolic", "jacobsen", "quinn2", "aboutanios", "newton")
WINDOWS = ("rectangular", "hann", "blackmanharris")

EPILOG = """\
examples:
  lidarctl scan --sim --data-dir /tmp/d --rows 40:60 --cols 20:50 --record-raw --json   # prints the scan id
  lidarctl reprocess --data-dir /tmp/d SCAN_ID --estimator jacobsen --out /tmp/jacobsen.ply
  lidarctl spectrum --data-dir /tmp/d SCAN_ID --pixel 48,30 --plot /tmp/px.png
"""


def _dsp_opts(sp) -> None:
    sp.add_argument("--estimator", choices=ESTIMATORS, default=None,
                    help="sub-bin frequency estimator (default: the one the scan used)")
    sp.add_argument("--pfa", type=float, default=None, metavar="P",
                    help="CFAR false-alarm probability, 0 < P < 0.1 (default: the scan's)")
    sp.add_argument("--window", choices=WINDOWS, default=None, help="range-FFT window (default: the scan's)")
    sp.add_argument("--phase-noise", choices=("on", "off"), default=None,
                    help="phase-noise compensation from the recorded monitor MZI (default: as scanned)")
    sp.add_argument("--data-dir", default=None, metavar="DIR",
                    help="work offline on this data directory instead of asking a daemon")


def add_parsers(sub) -> None:
    sp = sub.add_parser("reprocess", help="run the DSP again on a scan's raw capture",
                        description="Reprocess a scan recorded with --record-raw into a new, linked scan.",
                        epilog=EPILOG, formatter_class=base.HelpFormatter)
    daemon_opts(sp)
    sp.add_argument("id", help="scan ID of the recorded scan")
    _dsp_opts(sp)
    sp.add_argument("--out", default=None, metavar="FILE",
                    help="also write the new point cloud here (.ply, .las, .npz, .pcd or .mcap) with its FILE.json sidecar")
    sp.set_defaults(fn=cmd_reprocess)
    sp = sub.add_parser("spectrum", help="one pixel's spectra, CFAR threshold and detections",
                        description="Show one pixel's up/down range spectra from a scan's raw capture.",
                        epilog=EPILOG, formatter_class=base.HelpFormatter)
    daemon_opts(sp)
    sp.add_argument("id", help="scan ID of the recorded scan")
    sp.add_argument("--pixel", required=True, metavar="R,C", help="FPSA pixel as row,col indices")
    _dsp_opts(sp)
    sp.add_argument("--plot", default=None, metavar="FILE.png", help="draw the spectra into this PNG")
    sp.set_defaults(fn=cmd_spectrum)


def _settings(args):
    from ..raw import ReprocessSettings
    return ReprocessSettings(estimator=args.estimator, pfa=args.pfa, window=args.window,
                             phase_noise=None if args.phase_noise is None else args.phase_noise == "on")


def _body(args) -> dict[str, Any]:
    _settings(args)   # the same checks (and words) as the daemon's, before anything is sent
    return {k: v for k, v in (("estimator", args.estimator), ("pfa", args.pfa), ("window", args.window),
                              ("phase_noise", args.phase_noise)) if v is not None}


def _offline_store(args):
    from pathlib import Path

    from ..store import Store
    if not (Path(args.data_dir) / "lidard.sqlite3").is_file():
        raise CliError(f"--data-dir {args.data_dir}: not a lidard data directory (no lidard.sqlite3)")
    return Store(args.data_dir)


def cmd_reprocess(args) -> int:
    from ..pointcloud import format_of, sidecar_path
    fmt = format_of(args.out) if args.out else None
    body = _body(args)
    if args.data_dir is not None:
        from ..raw.service import reprocess_scan
        store = _offline_store(args)
        try:
            rec = reprocess_scan(store, args.id, _settings(args), formats=(fmt,) if fmt else None).to_dict()
            if args.out:
                src = store.data_dir / rec["files"][fmt]
                base.copy_atomic(src, args.out)
                base.copy_atomic(sidecar_path(src), sidecar_path(args.out))
        finally:
            store.close()
        flat = rec
    else:
        with client(args) as c:
            rec = c.request("POST", f"/scans/{args.id}/reprocess",
                            json={**body, **({"formats": [fmt]} if fmt else {})}).json()
            if args.out:
                base.write_bytes_atomic(args.out, c.request("GET", f"/scans/{rec['id']}/points",
                                                            params={"format": fmt}).content)
                base.write_bytes_atomic(sidecar_path(args.out), c.request(
                    "GET", f"/scans/{rec['id']}/sidecar", params={"format": fmt}).content)
        flat = {"id": rec["id"], "state": rec["state"], "partial": rec["partial"], "points": rec["counts"]["points"],
                "reprocessed_from": rec.get("reprocessed_from"), "wall_time_s": rec["timing"]["wall_time_s"]}
    s = {"id": flat["id"], "reprocessed_from": flat["reprocessed_from"], "state": flat["state"],
         "partial": bool(flat["partial"]), "points": flat["points"], "wall_time_s": flat["wall_time_s"],
         "out": args.out}
    if args.json:
        output.emit_json(s)
    else:
        print(f"scan {s['id']} (reprocessed from {s['reprocessed_from']}): {s['state']}"
              f"{' (partial)' if s['partial'] else ''}, {s['points']} points in {s['wall_time_s']:.3g} s"
              + (f", written to {args.out}" if args.out else ""))
    return 0


def _pixel(text: str) -> tuple[int, int]:
    try:
        r, c = (int(x) for x in text.replace(",", " ").split())
    except ValueError:
        raise CliError(f"--pixel: expected ROW,COL (two integers), got {text!r}") from None
    return r, c


def _spectrum_text(spec) -> str:
    rows = [[d["ramp"], d["bin"], f"{d['range_m']:.4f}", f"{d['snr_db']:.1f}",
             ",".join(k for k in ("harmonic", "unresolved") if d[k]) or "-"] for d in spec.detections]
    head = (f"pixel ({spec.row}, {spec.col}): estimator {spec.dsp['estimator']}, pfa {spec.dsp['pfa']:g}, "
            f"window {spec.dsp['window']}, phase-noise compensation "
            f"{'on' if spec.dsp['phase_noise_compensation'] else 'off'}; CFAR gate bins {spec.gate[0]}..{spec.gate[1]}")
    pts = [[f"{p['range']:.4f}", f"{p['velocity']:.4f}", f"{p['snr_db']:.1f}", int(p["return_index"]), int(p["valid"])]
           for p in spec.points]
    return "\n".join([head, "detections:", output.table(rows, ["RAMP", "BIN", "RANGE_M", "SNR_DB", "FLAGS"]),
                      "points:", output.table(pts, ["RANGE_M", "VELOCITY_MPS", "SNR_DB", "RETURN", "VALID"])])


def cmd_spectrum(args) -> int:
    from ..raw.spectrum import PixelSpectrum, plot_pixel_spectrum
    row, col = _pixel(args.pixel)
    body = _body(args)
    if args.data_dir is not None:
        from ..raw.service import scan_spectrum
        store = _offline_store(args)
        try:
            spec = scan_spectrum(store, args.id, row, col, _settings(args))
        finally:
            store.close()
    else:
        with client(args) as c:
            spec = PixelSpectrum.from_dict(c.get_json(f"/scans/{args.id}/spectrum",
                                                      params={"row": row, "col": col, **body}))
    if args.plot:
        plot_pixel_spectrum(spec, args.plot)
    if args.json:
        output.emit_json({**spec.to_dict(), "plot": args.plot})
    else:
        print(_spectrum_text(spec) + (f"\nplot written to {args.plot}" if args.plot else ""))
    return 0
