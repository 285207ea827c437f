"""``lidarctl calibrate``: the whole range and pointing calibration as one command, with progress.

The steps are the daemon's REST calls (lidard.api.routers.geometry), in the order a lab runs them:
the reference plate at each distance (``POST /calibration/range/plates``), the range fit
(``POST /calibration/range/fit``: effective monitor delay and zero offset; the chirp is re-linearized
against it), then the targets of known geometry (``POST /calibration/pointing``).

* Real hardware: the command asks for each plate position and waits for the operator (Enter; ``q``
  aborts, the plates measured so far stay pending), then for the pointing targets of ``--geometry``.
* Simulated bench: it places its own fixtures through the bench (``PUT /sim/scene``: the plate at each
  distance, then five spheres at 1 m), runs unattended and puts the bench's scene back at the end.
  ``POST /calibration/run`` is the same procedure as one REST call.

Plates left pending by an earlier, aborted run are listed and the command stops unless told to
``--keep-pending`` (they join this fit) or ``--drop-pending``. Mutating requests carry the control
lease (``--lease``/``LIDARD_LEASE``) when another client holds the lock.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from typing import Any
from collections.abc import Callable

from . import output
from .base import CliError
from .client import Client, client, daemon_opts
from .sim import _mutate


def add_parser(sub) -> None:
    sp = sub.add_parser("calibrate", help="guided range (plates) then pointing calibration on the daemon, with progress",
                        description=__doc__.split("\n\n", 1)[0].split(": ", 1)[1],
                        epilog=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    daemon_opts(sp)
    sp.add_argument("--plates", nargs="+", type=float, default=None, metavar="M",
                    help="plate distances along the optical axis in metres, at least two (default 0.8 1.1 1.4)")
    sp.add_argument("--geometry", default=None, metavar="FILE.toml",
                    help="the pointing targets' known geometry ([[sphere]] centre, radius / [[plane]] point, "
                         "normal; sensor frame, m); needed on real hardware, default on a simulated bench: "
                         "five 35 mm spheres at 1 m")
    pend = sp.add_mutually_exclusive_group()
    pend.add_argument("--keep-pending", action="store_true", help="plates pending from an earlier run join this fit")
    pend.add_argument("--drop-pending", action="store_true", help="forget plates pending from an earlier run first")
    sp.set_defaults(fn=cmd_calibrate)


def _say(args, text: str) -> None:
    """Progress on stderr (also with --json, whose one object goes to stdout)."""
    print(text, file=sys.stderr, flush=True)


def _geometry(args, simulated: bool) -> dict[str, Any]:
    from ..jobs.guided import FACTORY_GEOMETRY
    if args.geometry is None:
        if not simulated:
            raise CliError("calibrate: --geometry FILE.toml is needed on real hardware (the pointing targets' "
                           "known positions); see `lidarctl calibrate --help`")
        return FACTORY_GEOMETRY
    try:
        with open(args.geometry, "rb") as f:
            return tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise CliError(f"--geometry {args.geometry}: cannot read ({exc})") from None


def _pending(c: Client, args) -> list[dict[str, Any]]:
    from ..jobs.guided import pending_refusal
    waiting = c.get_json("/calibration/range/plates")
    if not waiting:
        return []
    if args.drop_pending:
        _mutate(c, "DELETE", "/calibration/range/plates")
        _say(args, f"dropped {len(waiting)} pending plate(s) of an earlier run")
        return []
    if args.keep_pending:
        _say(args, f"keeping {len(waiting)} pending plate(s) of an earlier run: "
                   + ", ".join(f"{m['id']} ({m['known_m']:g} m)" for m in waiting))
        return waiting
    raise CliError("calibrate: " + pending_refusal(waiting))


def _operator(prompt: str) -> None:
    try:
        answer = input(prompt)
    except EOFError:
        answer = "q"
    if answer.strip().lower() in ("q", "quit", "abort"):
        raise CliError("calibrate: aborted by the operator; plates measured so far stay pending "
                       "(the next run lists them: --keep-pending or --drop-pending)")


def cmd_calibrate(args) -> int:
    from ..instrument.calibration.pointing import parse_geometry, spheres_scene
    from ..instrument.calibration.range import plate_scene
    from ..jobs.guided import FACTORY_PLATES_M
    plates_m = tuple(args.plates) if args.plates else FACTORY_PLATES_M
    if len(set(plates_m)) < 2 or any(not d > 0 for d in plates_m):
        raise CliError(f"--plates: need at least two different positive distances in metres, got {list(plates_m)}")
    with client(args) as c:
        simulated = bool(c.get_json("/health").get("simulated"))
        geometry = _geometry(args, simulated)
        try:
            surfaces = parse_geometry(geometry, source=args.geometry or "<default targets>")
        except ValueError as exc:
            raise CliError(str(exc)) from None
        kept = _pending(c, args)
        restore = c.get_json("/sim/scene") if simulated else None
        place: Callable[[str, Any], None]
        if simulated:
            def place(what: str, scene: Any) -> None:
                _mutate(c, "PUT", "/sim/scene", json=scene)
        else:
            def place(what: str, scene: Any) -> None:
                _operator(f"{what}, then press Enter (q aborts): ")
        n = len(plates_m)
        steps = n + 2
        _say(args, f"calibrating {'the simulated bench (fixtures placed through the bench)' if simulated else 'the instrument'}: "
                   f"{n} plate(s) at {', '.join(f'{d:g}' for d in plates_m)} m, then {len(surfaces)} pointing target(s)")
        plates: list[dict[str, Any]] = []
        try:
            for i, d in enumerate(plates_m):
                place(f"[{i + 1}/{steps}] place the plate perpendicular to the optical axis at z = {d:g} m "
                      "from the lens centre", plate_scene(d))
                m = _mutate(c, "POST", "/calibration/range/plates", json={"known_m": d}, timeout=None)
                plates.append(m)
                _say(args, f"[{i + 1}/{steps}] plate at {d:g} m: raw range {m['raw_range_m']:.6f} m "
                           f"+- {m['sem_m'] * 1e6:.1f} um over {m['n']} pixels")
            rng = _mutate(c, "POST", "/calibration/range/fit")
            f = rng["fitted"]
            _say(args, f"[{n + 1}/{steps}] range calibration {rng['id']}: delay {f['delay_s'] * 1e9:.4f} ns, "
                       f"zero offset {f['zero_offset_m'] * 1e3:+.3f} mm")
            place(f"[{steps}/{steps}] place the pointing targets of {args.geometry}", spheres_scene(surfaces))
            pnt = _mutate(c, "POST", "/calibration/pointing", json={"geometry": geometry}, timeout=None)
            _say(args, f"[{steps}/{steps}] pointing calibration {pnt['id']}: residual "
                       f"{pnt['residuals']['rms_mm']:.3f} mm rms over {pnt['residuals'].get('points', '?')} points")
        finally:
            if restore is not None:
                _mutate(c, "PUT", "/sim/scene", json=restore)
    if args.json:
        output.emit_json({"range": rng, "pointing": pnt, "plates": plates, "kept_pending": kept})
    else:
        print(f"calibrated: range {rng['id']}, pointing {pnt['id']}; later scans use them")
    return 0
