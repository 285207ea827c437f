"""``lidarctl stream``: frames back to back, on the daemon (POST /streams) or with ``--sim`` on an embedded
simulated bench (lidard.jobs.stream_job).

``--frames N`` or until stopped: Ctrl-C or SIGTERM ends the frame in progress, keeps it (partial)
and every finished frame, and exits 130. ``--out DIR/`` writes one file per frame (``--format``) with
its JSON sidecar; ``--out FILE.mcap`` one message per frame. ``--pattern track --frame-rate HZ``
plans each frame from the last ones (lidard.instrument.tracking).
"""

from __future__ import annotations

import sys
import threading

from ..outputs.registry import FRAME_FORMATS
from . import base, output
from .base import CliError, Interrupted, signal_of
from .client import daemon_opts, refuse_sim_only
from .scan import _range

PATTERNS = ("raster", "serpentine", "roi", "track")


def add_parser(sub) -> None:
    sp = sub.add_parser("stream", help="run frames back to back (--sim: in process)",
                        description="Run a stream of frames: one bring-up, frames back to back, a pattern "
                                    "per frame (track: planned from the last frames).",
                        formatter_class=base.HelpFormatter)
    daemon_opts(sp, sim=True)
    sp.add_argument("--scene", default=None, metavar="FILE.toml", help="only with --sim: scene TOML")
    sp.add_argument("--pattern", choices=PATTERNS, default="raster", help="frame pattern (default raster)")
    sp.add_argument("--rows", default=None, metavar="A:B", help="FPSA rows A <= row < B")
    sp.add_argument("--cols", default=None, metavar="A:B", help="FPSA columns A <= col < B")
    sp.add_argument("--frames", type=int, default=None, metavar="N", help="stop after N frames (default: until stopped)")
    sp.add_argument("--frame-rate", type=float, default=None, metavar="HZ",
                    help="track: the frame rate the pixel budget of every frame is planned for (default 10)")
    sp.add_argument("--max-range", type=float, default=None, metavar="M", help="range gate in metres; points are reported up to 5 %% past it, none beyond")
    sp.add_argument("--max-speed", type=float, default=None, metavar="M/S",
                    help="fastest radial speed to measure, sizes the ADC's Doppler band (default: scan.max_speed_mps)")
    sp.add_argument("--averages", type=int, default=None, metavar="N", help="chirps averaged per pixel")
    sp.add_argument("--format", default="ply", choices=FRAME_FORMATS,
                    help="per-frame file format of --out DIR/ (default ply)")
    sp.add_argument("--out", default=None, metavar="DIR/|FILE.mcap",
                    help="a directory: one file per frame with its .json sidecar; FILE.mcap: one message per frame")
    sp.set_defaults(fn=cmd_stream)


def _spec(args, cfg):
    from ..instrument.frames import pixel_period_s
    from ..instrument.types import ScanRequest
    from ..jobs.stream_job import StreamSpec
    req = ScanRequest(pattern=args.pattern, rows=tuple(_range(args.rows, "rows")) if args.rows else None,
                      cols=tuple(_range(args.cols, "cols")) if args.cols else None,
                      averages=args.averages or cfg.scan.averages,
                      max_range_m=args.max_range or cfg.scan.max_range_m, max_speed_mps=args.max_speed,
                      formats=(args.format,))
    if args.pattern == "roi" and not (args.rows or args.cols):
        raise CliError("--pattern roi: give --rows and/or --cols")
    if args.frame_rate is not None and args.pattern != "track":
        raise CliError("--frame-rate: only --pattern track plans its frames to a frame rate")
    spec = StreamSpec(req, frames=args.frames, out=args.out,
                      frame_rate_hz=args.frame_rate if args.pattern == "track" else None,
                      pixel_s=pixel_period_s(cfg, req.averages))
    if args.pattern == "track" and spec.frame_rate_hz is None:
        spec.frame_rate_hz = 10.0
    try:
        spec.check()
    except ValueError as exc:
        raise CliError(str(exc)) from None
    return spec


def cmd_stream(args) -> int:
    from ..jobs.stream_job import StreamJob
    from .embedded import embedded, resolve, sim_config
    refuse_sim_only(args, "--scene", "--config", "--data-dir", "--no-cal-cache")
    if not args.sim:
        return _stream_daemon(args)
    cfg = sim_config(args)
    spec = _spec(args, cfg)
    job = StreamJob(spec)
    interrupted = [0]      # the signal that stopped the stream (SIGTERM/SIGHUP arrive as KeyboardInterrupt)
    job.on_frame = lambda f: print(f"frame {f.index}: {f.pixels_scanned}/{len(f.pixels)} pixels, "
                                   f"{int((f.points['valid'] == 1).sum())} valid points, start {f.start_s:.3f} s, "
                                   f"{f.hardware_time_s * 1e3:.1f} ms", file=sys.stderr)
    with embedded(args, cfg, scene_path=resolve(args.scene)) as (worker, _store, _inst):
        fut = worker.submit_task(lambda: job.run(worker))
        while True:
            try:
                result = fut.result()
                break
            except KeyboardInterrupt as exc:
                interrupted[0] = signal_of(exc)
                job.cancel.set()
            except Exception:      # the job records its failure (state "failed", error)
                result = None
                break
    st = job.status()
    if args.json:
        output.emit_json({**st, "frames": job.frames, "result": result, "interrupted": interrupted[0]})
    else:
        print(f"stream {job.id}: {st['state']}, {st['frames_done']} frames"
              + (f", written to {spec.out}" if spec.out else "") + (f" ({st['stop_reason']})" if st["stop_reason"] else ""))
    if interrupted[0]:
        raise Interrupted(f"stream {job.id} stopped, {st['frames_done']} frames kept", signum=interrupted[0])
    if st["state"] == "failed":
        raise CliError(f"stream {job.id} failed: {st['error']}")
    return 0


def _body(args) -> dict:
    body = {"pattern": args.pattern, "frames": args.frames, "frame_rate_hz": args.frame_rate,
            "max_range_m": args.max_range, "max_speed_mps": args.max_speed, "averages": args.averages,
            "format": "mcap" if (args.out or "").endswith(".mcap") else args.format}
    if args.pattern == "roi" and not (args.rows or args.cols):
        raise CliError("--pattern roi: give --rows and/or --cols")
    if args.frame_rate is not None and args.pattern != "track":
        raise CliError("--frame-rate: only --pattern track plans its frames to a frame rate")
    for name in ("rows", "cols"):
        if getattr(args, name):
            body[name] = _range(getattr(args, name), name)
    return {k: v for k, v in body.items() if v is not None}


def _stream_daemon(args) -> int:
    """POST /streams, report frames as they come, DELETE on Ctrl-C / SIGTERM, then fetch the files."""
    import json
    import time
    from pathlib import Path

    from .client import client
    body = _body(args)
    interrupted = [0]
    stop = threading.Event()
    with client(args) as c:
        sid = c.request("POST", "/streams", json=body).json()["id"]
        seen, deleted = 0, False
        while True:
            try:
                if stop.is_set() and not deleted:
                    deleted = True
                    c.request("DELETE", f"/streams/{sid}")
                st = c.get_json(f"/streams/{sid}")
                for f in st["frames"][seen:]:
                    print(f"frame {f['frame']}: {f['pixels_scanned']}/{f['pixels_planned']} pixels, "
                          f"{f['valid_points']} valid points, start {f['start_s']:.3f} s", file=sys.stderr)
                seen = len(st["frames"])
                if st["state"] not in ("queued", "running"):
                    break
                time.sleep(0.2)     # polling interval of the frame report
            except KeyboardInterrupt as exc:    # Ctrl-C, SIGTERM, SIGHUP: DELETE, keep polling
                interrupted[0] = signal_of(exc)
                stop.set()
        if args.out:
            if body["format"] == "mcap":
                base.write_bytes_atomic(args.out, c.request("GET", f"/streams/{sid}/mcap").content)
            else:
                out = Path(args.out)
                out.mkdir(parents=True, exist_ok=True)
                from ..outputs import sidecar_path, suffix_of
                for f in st["frames"]:
                    path = out / f"frame_{f['frame']:05d}{suffix_of(body['format'])}"
                    base.write_bytes_atomic(path, c.request("GET", f"/streams/{sid}/frames/{f['frame']}").content)
                    base.write_bytes_atomic(sidecar_path(path), json.dumps(f, indent=1).encode())
    if args.json:
        output.emit_json({**st, "interrupted": interrupted[0]})
    else:
        print(f"stream {sid}: {st['state']}, {st['frames_done']} frames" + (f", written to {args.out}" if args.out else "")
              + (f" ({st['stop_reason']})" if st.get("stop_reason") else ""))
    if interrupted[0]:
        raise Interrupted(f"stream {sid} stopped, {st['frames_done']} frames kept", signum=interrupted[0])
    if st["state"] == "failed":
        raise CliError(f"stream {sid} failed: {st.get('error')}")
    return 0
