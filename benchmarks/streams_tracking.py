"""Benchmark: streams of frames and the ``track`` pattern on the simulated bench (embedded).

Scenes: a wall at 2.5 m and a 3 x 3 cm box (1 cm deep) either crossing sideways at 0.1 m/s at 1.0 m
("crossing", scan.max_speed_mps of config/sim.toml) or approaching from 2.2 m at 1 m/s ("approaching",
max_speed_mps 1.5 so that its Doppler is inside the ADC band); ROI rows/cols [16, 112). Per stream:
frames, the hardware frame rate (frames after the first / time between the first and last frame's
first triggers), the per-frame overhead (share of the frame period not spent triggering pixels:
set-up commands and the read-out still draining when the triggers end), the track yield (valid points
on the box per frame, found with the bench's ground truth at each point's t), and the survey
(revisit time, pixels per frame). Also a fixed ROI stream's overhead at 10 Hz-sized frames (with the
digitizer set-ups it needed: one acquisition runs across frames), and the approaching box at the
configuration's default max_speed_mps (0.4 m/s: what its 1 m/s does to the points on it).

Run: nice python benchmarks/streams_tracking.py [--frames 20] [--rates 5,10,20] [--parts track,fixed,default_speed]
     [--markdown FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import threading

import numpy as np

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument
from lidard.dsp.detect.gate import PointFlag
from lidard.instrument.frames import FramePlan
from lidard.instrument.plan import plan
from lidard.instrument.tracking import TrackParams, track_planner

ROI = ScanRequest(pattern="roi", rows=(16, 112), cols=(16, 112), max_range_m=3.0)
WALL = {"kind": "plane", "point": [0.0, 0.0, 2.5], "normal": [0.0, 0.0, -1.0], "reflectivity": 0.9}


def scene(kind: str) -> dict:
    if kind == "crossing":
        box = {"kind": "box", "center": [-0.09, 0.0, 1.0], "size": [0.03, 0.03, 0.01], "reflectivity": 0.8,
               "velocity": [0.1, 0.0, 0.0]}
    else:
        box = {"kind": "box", "center": [0.0, 0.0, 2.2], "size": [0.03, 0.03, 0.01], "reflectivity": 0.8,
               "velocity": [0.0, 0.0, -1.0]}
    return {"target": [box, WALL]}


def in_view(inst, kind: str, t_s: float) -> bool:
    """The whole box inside the ROI's columns at time t (the crossing box leaves the field after ~2 s),
    or the approaching box still 0.1 m or more in front of the sensor (it reaches it after 2.1 s)."""
    if kind != "crossing":
        return 2.2 - 0.005 - t_s >= 0.1
    d = inst.optics.directions(np.array([64, 64]), np.array([ROI.cols[0], ROI.cols[1] - 1]))
    x = np.sort(d[:, 0] / d[:, 2])             # x / z of the ROI's edge columns
    cx = -0.09 + 0.1 * t_s
    return bool(x[0] <= cx - 0.015 and cx + 0.015 <= x[1])


def run_stream(inst, bench, planner, frames: int, cal=None, req=ROI):
    got = []
    res = inst.run_stream(req, planner, got.append, threading.Event(), cal, frames=frames)
    on_box = []
    for f in got:
        v = f.points[f.points["valid"] == 1]
        truth = bench.ground_truth(v["row"], v["col"], v["t"])
        # on the object: the bench's first hit of that beam at the point's t is the box (not the wall),
        # and the point is not a wall return (the uncalibrated range carries a few cm of zero offset)
        on_box.append(int(np.sum((truth < 2.3) & (v["range"] < 2.3))))
    starts = np.array([f.start_s for f in got])
    period = np.diff(starts)
    trig = np.array([f.pixels_scanned * f.pixel_period_s for f in got[:-1]])
    rate = (len(got) - 1) / (starts[-1] - starts[0]) if len(got) > 1 else float("nan")
    overhead = float(np.sum(period - trig) / np.sum(period)) if len(period) else float("nan")
    return res, got, np.array(on_box), rate, overhead


def default_speed(inst, bench, cal, frames: int) -> dict:
    """The approaching box (1 m/s) at the configuration's max_speed_mps: the ADC band and the ramps'
    pairing are sized for that speed; what becomes of the box's returns."""
    inst.set_scene(scene("approaching"))
    req = ROI
    pixel_s = inst.cfg.chirp.period_s + inst.cfg.scan.settle_s
    planner = track_planner(req, inst.optics, TrackParams(frame_rate_hz=10.0, pixel_s=pixel_s))
    res, got, on_box, _, _ = run_stream(inst, bench, planner, frames, cal, req)
    seen = np.array([in_view(inst, "approaching", f.start_s + 0.5 * f.hardware_time_s) for f in got])
    pts = np.concatenate([f.points for f in got])
    truth = bench.ground_truth(pts["row"], pts["col"], pts["t"])
    box = (truth < 2.3) & (np.abs(pts["range"] - truth) < 0.1)     # returns near the box's true range
    flags = {}
    for fl in PointFlag:
        n = int(np.sum(box & ((pts["flags"] & int(fl)) != 0)))
        if n:
            flags[fl.name] = n
    v_max = inst.cfg.scan.max_speed_mps
    lam = inst.cfg.chirp.wavelength_m
    good = box & (pts["valid"] == 1)
    # the range gate tops out at the beat of max_range_m plus the Doppler of max_speed_mps: a target
    # faster than that speed shows a beat above the gate (range beat + its Doppler) until it is nearer than
    hz_per_m = 2 * inst.cfg.chirp.rate_hz_per_s / 299_792_458.0
    limit_m = req.max_range_m - 2 * (1.0 - v_max) / lam / hz_per_m
    first = next((k for k, n in enumerate(on_box) if n >= 5), None)
    return {"max_speed_mps": v_max, "band_mhz": 2 * v_max / lam / 1e6, "doppler_mhz": 2 * 1.0 / lam / 1e6,
            "yield": f"{100 * np.mean(on_box[seen] >= 5):.0f} % of {int(seen.sum())}",
            "box_returns": int(box.sum()), "box_valid": int(good.sum()), "flags": flags,
            "fast_valid": int(np.sum(good & (np.abs(pts["velocity"]) > v_max))), "stop": res.stop_reason,
            "limit_m": limit_m, "first_frame": first, "per_frame": on_box.tolist(),
            "first_range_m": None if first is None else 2.2 - 1.0 * (got[first].start_s + 0.5 * got[first].hardware_time_s)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--rates", default="5,10,20")
    ap.add_argument("--parts", default="track,fixed,default_speed")
    ap.add_argument("--markdown", default=None)
    a = ap.parse_args(argv)
    parts = set(a.parts.split(","))
    cfg = load_config("config/sim.toml")
    inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    bench = inst._on_close.__self__
    pixel_s = cfg.chirp.period_s + cfg.scan.settle_s
    rows, fixed, slow = [], None, None
    cpu0 = resource.getrusage(resource.RUSAGE_SELF).ru_utime
    try:
        cal = inst.linearize()
        for kind in ("crossing", "approaching") if "track" in parts else ():
            for hz in [float(x) for x in a.rates.split(",")]:
                inst.set_scene(scene(kind))
                # the approaching box's 1 m/s must fit the ADC's Doppler band (scan.max_speed_mps is 0.4)
                req = ROI if kind == "crossing" else dataclasses.replace(ROI, max_speed_mps=1.5)
                planner = track_planner(req, inst.optics, TrackParams(frame_rate_hz=hz, pixel_s=pixel_s))
                res, got, on_box, rate, overhead = run_stream(inst, bench, planner, a.frames, cal, req)
                seen = np.array([in_view(inst, kind, f.start_s + 0.5 * f.hardware_time_s) for f in got])
                on_box = on_box[seen]
                tr = [f.trade for f in got]
                rows.append((kind, hz, rate, overhead, f"{100 * np.mean(on_box >= 5):.0f} % of {len(on_box)}", int(on_box.min()),
                             float(np.median(on_box)), float(np.mean([t["pixels"] for t in tr])),
                             float(np.mean([t["survey_pixels"] for t in tr])),
                             float(np.median([t["survey_revisit_s"] for t in tr])), res.stop_reason,
                             float(np.median([f.setup_s for f in got[1:]]))))
                print(rows[-1], flush=True)
        if "default_speed" in parts:
            slow = default_speed(inst, bench, cal, a.frames)
            print("default speed", slow, flush=True)
        if "fixed" in parts:
            inst.set_scene({"target": [WALL]})
            # 396 pixels: 96 ms of triggers, a 10 Hz frame
            px = plan(ScanRequest(pattern="roi", rows=(40, 64), cols=(40, 62)), inst.optics)
            res, got, _, rate, overhead = run_stream(inst, bench, lambda k, h: FramePlan(px), a.frames, cal)
            setup = np.array([f.setup_s for f in got[1:]])
            fixed = (len(px), rate, overhead, float(np.median(setup)), res.meta["digitizer_arms"],
                     float(setup.max()))
            print("fixed", fixed, flush=True)
    finally:
        inst.close()
    cpu = resource.getrusage(resource.RUSAGE_SELF).ru_utime - cpu0
    load = os.getloadavg()[0]
    lines = ["| scene | --frame-rate (Hz) | hardware frame rate (Hz) | overhead | median gap (ms) | frames with >= 5 points on the "
             "object (of the frames it is in view) | min / median points on it | pixels per frame | survey pixels per frame | survey revisit (s) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r[0]} | {r[1]:g} | {r[2]:.2f} | {100 * r[3]:.1f} % | {1e3 * r[11]:.2f} | {r[4]} | {r[5]} / {r[6]:.0f} "
                     f"| {r[7]:.0f} | {r[8]:.0f} | {r[9]:.2f} |")
    lines.append("")
    if fixed is not None:
        lines.append(f"Fixed {fixed[0]}-pixel ROI stream, {a.frames} frames: hardware frame rate {fixed[1]:.2f} Hz, "
                     f"overhead {100 * fixed[2]:.1f} % of the frame period, gap between frames median "
                     f"{1e3 * fixed[3]:.2f} ms (max {1e3 * fixed[5]:.2f} ms), digitizer set up {fixed[4]} time(s).")
    if slow is not None:
        lines.append(f"Approaching box at 1 m/s, --frame-rate 10, default max_speed_mps "
                     f"({slow['max_speed_mps']:g} m/s, Doppler band +-{slow['band_mhz']:.2f} MHz against the box's "
                     f"{slow['doppler_mhz']:.2f} MHz): frames with >= 5 valid points on the box {slow['yield']}; of the "
                     f"box's beams' returns in all frames {slow['box_returns']} detected, {slow['box_valid']} valid, "
                     f"flags of the rest {slow['flags']}; valid points on the box with |velocity| > "
                     f"{slow['max_speed_mps']:g} m/s: {slow['fast_valid']}. Points on the box per frame "
                     f"{slow['per_frame']}: the first frame with >= 5 is frame {slow['first_frame']}, the box then "
                     f"at {slow['first_range_m']:.2f} m; the range gate (max_range_m {ROI.max_range_m:g} m of beat plus "
                     f"the Doppler of {slow['max_speed_mps']:g} m/s) holds the beat of a 1 m/s approaching return on the ramp where its Doppler adds to the range beat "
                     f"only nearer than {slow['limit_m']:.2f} m.")
    lines.append(f"CPU {cpu:.0f} s, load average {load:.2f} (2-core Xeon).")
    text = "\n".join(lines)
    print(text)
    if a.markdown:
        with open(a.markdown, "w") as fh:
            fh.write(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
