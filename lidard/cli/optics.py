"""Offline figures, no daemon: ``lidarctl optics`` prints the FPSA figures of Table 4-1 (eqs. 4-1..4-16)
for a profile and lens; ``lidarctl budget`` the link budget of §2.4.1 (eqs. 2-9..2-21, Fig. 2-8) at
one distance."""

from __future__ import annotations

from . import base, output
from .base import CliError


def add_parsers(sub) -> None:
    sp = sub.add_parser("optics", help="FPSA field of view, resolution, divergence (Table 4-1)")
    sp.add_argument("--profile", required=True, help="scanner profile: fpsa20, fpsa128, ... (config/profiles)")
    sp.add_argument("--lens", default=None, help="lens name from the profile (default: the profile's)")
    sp.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
    sp.set_defaults(fn=cmd_optics)

    sp = sub.add_parser("budget", help="link budget and SNR at a distance (§2.4.1)")
    sp.add_argument("--profile", default=None, help="scanner profile (default: the configuration's)")
    sp.add_argument("--distance", type=float, required=True, metavar="M", help="target distance in metres, > 0")
    sp.add_argument("--power", type=float, default=None, metavar="W",
                    help="source optical power in watts, > 0 (default: the configuration's link.laser_power_w)")
    sp.add_argument("--config", default=None, metavar="FILE.toml", help="configuration TOML (default search path)")
    sp.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
    sp.set_defaults(fn=cmd_budget)


def cmd_optics(args) -> int:
    from ..config import load_profile
    profile = load_profile(args.profile)
    s = profile.optics(args.lens).summary()
    s = {"profile": profile.name, "lens": args.lens or profile.default_lens, **s}
    if args.json:
        output.emit_json(s)
        return 0
    print(f"profile {s['profile']}, lens {s['lens']} (f = {s['focal_m'] * 1e3:.3g} mm)")
    print(f"  field of view      {s['fov_deg'][0]:8.3f} x {s['fov_deg'][1]:.3f} deg")
    print(f"  resolution         {s['resolution_deg'][0]:8.4f} x {s['resolution_deg'][1]:.4f} deg")
    print(f"  divergence (W/f)   {s['divergence_deg'][0]:8.4f} x {s['divergence_deg'][1]:.4f} deg")
    print(f"  pixels             {s['pixels'][0]} x {s['pixels'][1]} ({s['bonded_rows']} rows bonded)")
    return 0


def cmd_budget(args) -> int:
    from ..physics.budget import budget_report
    if not (args.distance > 0):
        raise CliError(f"--distance must be > 0 m, got {args.distance}")
    if args.power is not None and not (args.power > 0):
        raise CliError(f"--power must be > 0 W, got {args.power}")
    cfg = base.load_config(args.config, args.profile)
    lp = cfg.link_params()
    if args.power is not None:
        lp = lp.with_(source_power_w=args.power)
    rep = budget_report(lp, args.distance)
    rep = {"profile": cfg.profile, "reference": cfg.link.reference, **rep}
    if args.json:
        output.emit_json(rep)
        return 0
    print(f"link budget at {rep['distance_m']:g} m ({cfg.profile}, {cfg.link.reference} reference, "
          f"source {rep['source_power_w'] * 1e3:.3g} mW)")
    print(f"  {'component':<10} {'ASD (V/rtHz)':>14}")
    for k, v in rep["asd_v_per_rthz"].items():
        print(f"  {k:<10} {v:14.4e}")
    print(f"  {'total noise':<10} {rep['noise_total_v_per_rthz']:13.4e}")
    print(f"  SNR {rep['snr_db']:.2f} dB, dominant noise {rep['dominant_noise']}, "
          f"max range {rep['max_range_m']:.4g} m")
    return 0
