"""``lidarctl reprocess`` and ``lidarctl spectrum``: replay a scan's raw capture.

Both work on a scan recorded with ``record_raw`` (``lidarctl scan --record-raw``): through a running
daemon (``POST /scans/{id}/reprocess``, ``GET /scans/{id}/spectrum``), or offline on a data
directory with ``--data-dir DIR`` (no daemon may hold it: the store's lock refuses a second owner).
Reprocessing runs the scan DSP again with the original settings unless overridden, and writes a new
scan linked to the original (``reprocessed_from``).

Offline, the raw Zarr chunks are independent tasks (``lidard.raw.replay.reprocess_chunk``, the unchanged
DSP) and may run on Dask: ``--scheduler ADDRESS`` uses an existing
``dask.distributed`` scheduler, ``--dask`` / ``--workers N`` start a LocalCluster of worker processes.
Without any of these the default is a LocalCluster when the ``offline`` extra is installed and the work
has more than one chunk, else this process; ``--in-process`` forces this process. The results come back
in chunk order, so the merged cloud is in pixel order and equals the in-process one point for point.
Several scans (``ID1 ID2 ... --same-settings``) share one client/cluster.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from . import base, output
from .base import CliError
from .client import client, daemon_opts
from .progress import MODES, Progress

ESTIMATORS = ("argmax", "parabolic", "jacobsen", "quinn2", "aboutanios", "newton")
WINDOWS = ("rectangular", "hann", "blackmanharris")

EPILOG = """\
examples:
  lidarctl scan --sim --data-dir /tmp/d --rows 40:60 --cols 20:50 --record-raw --json   # prints the scan id
  lidarctl reprocess --data-dir /tmp/d SCAN_ID --estimator jacobsen --out /tmp/jacobsen.ply
  lidarctl reprocess --data-dir /tmp/d SCAN_ID --workers 4                 # a LocalCluster of 4 processes
  lidarctl reprocess --data-dir /tmp/d ID1 ID2 --same-settings --pfa 1e-9 --scheduler tcp://host:8786
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


def _dask_opts(sp) -> None:
    sp.add_argument("--same-settings", action="store_true",
                    help="reprocess several scans, applying the same overrides to each")
    sp.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="with --data-dir: run the chunks on this dask.distributed scheduler (tcp://host:8786)")
    sp.add_argument("--dask", action="store_true",
                    help="with --data-dir: start a LocalCluster of worker processes (one per CPU)")
    sp.add_argument("--workers", type=int, default=None, metavar="N",
                    help="with --data-dir: start a LocalCluster of N worker processes (implies --dask)")
    sp.add_argument("--in-process", action="store_true",
                    help="with --data-dir: run the chunks in this process, never on Dask")
    sp.add_argument("--progress", choices=MODES, default="auto",
                    help="stderr progress of an offline reprocessing (bar, lines, json or none)")


def add_parsers(sub) -> None:
    sp = sub.add_parser("reprocess", help="run the DSP again on a scan's raw capture",
                        description="Reprocess a scan recorded with --record-raw into a new, linked scan.",
                        epilog=EPILOG, formatter_class=base.HelpFormatter)
    daemon_opts(sp)
    sp.add_argument("id", nargs="+", help="scan ID(s) of recorded scans (several need --same-settings)")
    _dsp_opts(sp)
    _dask_opts(sp)
    sp.add_argument("--out", default=None, metavar="FILE",
                    help="also write the new point cloud here (.ply, .las, .npz, .pcd, .mcap or .ros2.mcap) with its "
                         "FILE.json sidecar; the directory must exist")
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
    # absolute: the chunk tasks carry the capture's path, and a remote worker's cwd is not ours
    return Store(Path(args.data_dir).expanduser().resolve())


DASK_MODULES = ("dask", "distributed")


def missing_dask() -> list[str]:
    """The packages of the ``offline`` extra that Dask reprocessing needs and this Python lacks."""
    import importlib.util
    return [m for m in DASK_MODULES if importlib.util.find_spec(m) is None]


def _require_dask(flag: str) -> None:
    from ..offline import INSTALL_HINT
    missing = missing_dask()
    if missing:
        raise CliError(f"{flag} needs the offline extra (missing: {', '.join(missing)}); "
                       f"install it with: {INSTALL_HINT}")


def _check_flags(args) -> None:
    ids = args.id
    if len(ids) > 1 and not args.same_settings:
        raise CliError(f"{len(ids)} scan IDs given: add --same-settings to apply the same overrides to each")
    if len(ids) > 1 and args.out:
        raise CliError("--out takes one scan: give one ID, or leave --out out and read each new scan")
    if args.workers is not None and args.workers < 1:
        raise CliError(f"--workers must be at least 1, got {args.workers}")
    dask_flags = [f for f, on in (("--scheduler", args.scheduler), ("--dask", args.dask),
                                  ("--workers", args.workers is not None)) if on]
    if args.in_process and dask_flags:
        raise CliError(f"--in-process contradicts {' '.join(dask_flags)}")
    if args.scheduler and (args.dask or args.workers is not None):
        raise CliError("--scheduler uses an existing cluster: leave out --dask/--workers")
    if args.data_dir is None and (dask_flags or args.in_process):
        raise CliError(f"{' '.join(dask_flags) or '--in-process'} works offline only: add --data-dir DIR "
                       "(a daemon reprocesses in its own process)")


def _total_chunks(store, ids) -> int:
    from ..errors import LidardError
    from ..raw.replay import chunk_count
    from ..jobs.reprocess import raw_path
    total = 0
    for sid in ids:
        try:
            total += chunk_count(raw_path(store, sid))
        except LidardError:     # reprocess_scan names the missing scan/capture in its own words
            pass
    return total


def _plan(args, n_chunks: int) -> tuple[str, int | None]:
    """("scheduler" | "local" | "in-process", LocalCluster workers): flags first, then the default."""
    import os
    if args.scheduler:
        _require_dask("--scheduler")
        return "scheduler", None
    if args.in_process:
        return "in-process", None
    if args.dask or args.workers is not None:
        _require_dask("--workers" if args.workers is not None else "--dask")
        return "local", args.workers or os.cpu_count() or 1
    if n_chunks > 1 and not missing_dask():
        return "local", max(1, min(os.cpu_count() or 1, n_chunks))
    return "in-process", None


@contextmanager
def _executor(args, mode: str, n_workers: int | None) -> Iterator[tuple[Any, str]]:
    """(Dask client or None, the words saying where the chunks run)."""
    if mode == "in-process":
        yield None, "in-process"
        return
    from ..offline.cluster import ClusterError, open_client
    try:
        with open_client(args.scheduler, n_workers=n_workers, processes=True) as c:
            where = (f"dask scheduler {args.scheduler}" if mode == "scheduler"
                     else f"dask LocalCluster ({n_workers} worker processes)")
            yield c, where
    except ClusterError as exc:
        raise CliError(str(exc)) from None


def _progress_fn(bar: Progress, sid: str, n_pixels: int):
    def on_progress(done: int, total: int, failed: int) -> None:
        frac = done / total if total else 1.0
        bar({"event": "progress", "stage": f"reprocess {sid}", "fraction": frac,
             "pixels_done": round(frac * n_pixels), "pixels_planned": n_pixels, "points": 0})
    return on_progress


def _reprocess_offline(args, fmt: str | None) -> list[dict[str, Any]]:
    from ..offline.cluster import TasksFailed, mapper
    from ..outputs import sidecar_path
    from ..raw.capture import RawCapture
    from ..jobs.reprocess import raw_path, reprocess_scan
    store = _offline_store(args)
    settings = _settings(args)
    out = []
    try:
        mode, n_workers = _plan(args, _total_chunks(store, args.id))
        with _executor(args, mode, n_workers) as (dask_client, where):
            print(f"reprocessing {len(args.id)} scan(s): {where}", file=sys.stderr)
            for sid in args.id:
                bar = Progress(args.progress)
                try:
                    path = raw_path(store, sid)
                    n_pix = RawCapture(path).n_pixels if (path / "zarr.json").is_file() else 0
                    fn = mapper(dask_client, on_progress=_progress_fn(bar, sid, n_pix))
                    rec = reprocess_scan(store, sid, settings, formats=(fmt,) if fmt else None, map_fn=fn).to_dict()
                except TasksFailed as exc:
                    raise CliError(f"scan {sid}: {exc}") from None
                finally:
                    bar.close()
                if args.out:
                    src = store.data_dir / rec["files"][fmt]
                    base.copy_atomic(src, args.out)
                    base.copy_atomic(sidecar_path(src), sidecar_path(args.out))
                out.append({**rec, "executor": where})
    finally:
        store.close()
    return out


def _reprocess_daemon(args, body: dict[str, Any], fmt: str | None) -> list[dict[str, Any]]:
    from ..outputs import sidecar_path
    out = []
    with client(args) as c:
        for sid in args.id:
            rec = c.request("POST", f"/scans/{sid}/reprocess",
                            json={**body, **({"formats": [fmt]} if fmt else {})}).json()
            if args.out:
                base.write_bytes_atomic(args.out, c.request("GET", f"/scans/{rec['id']}/points",
                                                            params={"format": fmt}).content)
                base.write_bytes_atomic(sidecar_path(args.out), c.request(
                    "GET", f"/scans/{rec['id']}/sidecar", params={"format": fmt}).content)
            out.append({"id": rec["id"], "state": rec["state"], "partial": rec["partial"],
                        "points": rec["counts"]["points"], "reprocessed_from": rec.get("reprocessed_from"),
                        "wall_time_s": rec["timing"]["wall_time_s"], "executor": "daemon"})
    return out


def cmd_reprocess(args) -> int:
    from ..outputs import format_of
    _check_flags(args)
    fmt = format_of(args.out) if args.out else None
    base.check_out(args.out)
    body = _body(args)
    flats = _reprocess_offline(args, fmt) if args.data_dir is not None else _reprocess_daemon(args, body, fmt)
    summaries = [{"id": f["id"], "reprocessed_from": f["reprocessed_from"], "state": f["state"],
                  "partial": bool(f["partial"]), "points": f["points"], "wall_time_s": f["wall_time_s"],
                  "executor": f["executor"], "out": args.out} for f in flats]
    if args.json:
        output.emit_json(summaries[0] if len(summaries) == 1 else summaries)
        return 0
    for s in summaries:
        print(f"scan {s['id']} (reprocessed from {s['reprocessed_from']}): {s['state']}"
              f"{' (partial)' if s['partial'] else ''}, {s['points']} points in {s['wall_time_s']:.3g} s"
              f" ({s['executor']})" + (f", written to {args.out}" if args.out else ""))
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
        from ..jobs.reprocess import scan_spectrum
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
