"""The ``track`` pattern: a stream's next frame planned from its last frames' points (dissertation §4.1
random access; §5.2.2: "regions with objects of interest scanned with a higher resolution").

A pure function of the last frames (:func:`plan_track`; no I/O, no clock), tested without a bench.
Each frame gets a pixel budget from the frame rate and the hardware time one pixel costs
(``budget = margin / frame_rate / seconds_per_pixel``; the seconds per pixel are measured on the
frames so far when there are two, since the digitizer's read-out can cost more than the triggers;
the chirp's ``pixel_s`` before). The budget is split:

* **dense regions** around the returns of interest in the last frames: a return is of interest when
  it moves (``|radial velocity| >= speed_mps``) or stands in front of its surroundings (nearer by
  ``change_m`` than the farthest return of the history within ``neighbourhood`` pixels: an object
  before a background). Those returns are grouped (connected pixels), each group matched to the
  nearest group of an older frame for its lateral motion (pixels per second), and its box is moved
  to where it will be at the middle of the next frame, widened by the motion over one frame, and
  scaled by the range change its radial velocity predicts (an approaching object grows). Every
  bonded pixel of the boxes is scanned (or every ``stride``-th when the boxes exceed their share);
* **survey**: the adaptive pattern's coarse grid (:func:`lidard.instrument.plan.coarse_plan`, shared with
  ``adaptive``), visited in a low-discrepancy order, a slice per frame continuing where the last
  frame's stopped, so the whole field is revisited every ``revisit`` frames and a new object is
  found within one revisit time.

The trade is stated per frame (``FramePlan.trade``, the sidecar's ``plan``): budget, survey pixels,
revisit time, dense pixels and area, the tracks with their predicted motion.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from .frames import FramePlan
from .types import ScanRequest
from ..physics.optics import FpsaOptics
from .plan import ADAPTIVE_STEP, coarse_plan, selected_cols, selected_rows

GOLDEN = 0.6180339887498949   # the survey's visiting order: i x golden mod 1 spreads any slice over the field


@dataclass(frozen=True)
class TrackParams:
    """The tracking planner's parameters (defaults for the 1-2 m scenes of config/sim.toml)."""

    frame_rate_hz: float = 10.0
    pixel_s: float = 243e-6          # hardware time of one pixel from the chirp (period x averages + settle)
    margin: float = 0.95             # of the frame period the budget fills (the rest: set-up jitter)
    survey_share: float = 0.3        # of the budget kept for the survey while tracks take the rest
    step: int = ADAPTIVE_STEP        # survey grid spacing (bonded rows and columns)
    speed_mps: float = 0.2           # |radial velocity| that marks a moving return
    change_m: float = 0.15           # nearer than its neighbourhood's farthest return by this: foreground
    # pixels (square) of that neighbourhood: wide enough that the sparse survey finds background around
    # a small object (two survey cells each side), not only at its edges
    neighbourhood: int = 4 * ADAPTIVE_STEP + 1
    pad_px: int = 2                  # box margin around a track (pixels), besides its motion
    gate_px: float = 12.0            # largest centroid jump matched between frames (pixels)

    def __post_init__(self):
        if not self.frame_rate_hz > 0:
            raise ValueError(f"frame_rate_hz: {self.frame_rate_hz} must be > 0")
        if not self.pixel_s > 0:
            raise ValueError(f"pixel_s: {self.pixel_s} must be > 0")
        if not 0 < self.survey_share < 1:
            raise ValueError(f"survey_share: {self.survey_share} must be inside (0, 1)")


def seconds_per_pixel(history: Sequence, p: TrackParams) -> float:
    """Hardware time a pixel costs, set-up and read-out included: measured on the last two frames'
    start times when there are two, else twice the chirp's ``pixel_s`` (a first guess that the
    read-out roughly doubles it on a bus slower than the records arrive)."""
    if len(history) >= 2:
        a, b = history[-2], history[-1]
        n = len(a.pixels)
        if n and b.start_s > a.start_s:
            return max(p.pixel_s, (b.start_s - a.start_s) / n)
    return 2.0 * p.pixel_s


def frame_budget(history: Sequence, p: TrackParams) -> int:
    return max(1, int(p.margin / p.frame_rate_hz / seconds_per_pixel(history, p)))


def survey_order(request: ScanRequest, optics: FpsaOptics, step: int) -> np.ndarray:
    """The coarse grid of ``adaptive`` in a low-discrepancy order (any slice spread over the field)."""
    coarse = coarse_plan(request, optics, step)
    return coarse[np.argsort((np.arange(len(coarse)) * GOLDEN) % 1.0, kind="stable")]


def _interesting(history: Sequence, p: TrackParams, shape: tuple[int, int]) -> list[np.ndarray]:
    """Per frame (oldest first): its valid points that move or stand before their surroundings."""
    far = np.full(shape, -np.inf)
    for f in history:
        v = f.points[f.points["valid"] == 1]
        np.maximum.at(far, (v["row"], v["col"]), v["range"].astype(np.float64))
    far = ndimage.maximum_filter(far, size=p.neighbourhood, mode="nearest")
    out = []
    for f in history:
        v = f.points[(f.points["valid"] == 1) & (f.points["return_index"] == 0)]
        fg = v["range"] < far[v["row"], v["col"]] - p.change_m
        out.append(v[fg | (np.abs(v["velocity"]) >= p.speed_mps)])
    return out


def _groups(pts: np.ndarray, shape: tuple[int, int], join_px: int) -> list[np.ndarray]:
    if len(pts) == 0:
        return []
    mask = np.zeros(shape, bool)
    mask[pts["row"], pts["col"]] = True
    lab, n = ndimage.label(ndimage.binary_dilation(mask, iterations=join_px))
    which = lab[pts["row"], pts["col"]]
    return [pts[which == k] for k in range(1, n + 1)]


def _tracks(history: Sequence, p: TrackParams, shape: tuple[int, int]) -> list[dict[str, Any]]:
    """Groups of interesting returns in the newest frame that has some, with their lateral motion
    (matched to the nearest group of an older frame) and mean radial velocity and range."""
    per_frame = _interesting(history, p, shape)
    newest = next((i for i in range(len(history) - 1, -1, -1) if len(per_frame[i])), None)
    if newest is None:
        return []
    older = [(i, g) for i in range(newest) for g in _groups(per_frame[i], shape, p.step)]
    tracks = []
    for g in _groups(per_frame[newest], shape, p.step):
        c = np.array([g["row"].mean(), g["col"].mean()])
        t = float(g["t"].mean())
        vel = np.zeros(2)
        best = None
        for i, o in older:   # the most recent older group within the gate
            co = np.array([o["row"].mean(), o["col"].mean()])
            if np.hypot(*(c - co)) <= p.gate_px and (best is None or i >= best[0]):
                best = (i, co, float(o["t"].mean()))
        if best is not None and t > best[2]:
            vel = (c - best[1]) / (t - best[2])
        tracks.append({"rows": (int(g["row"].min()), int(g["row"].max())),
                       "cols": (int(g["col"].min()), int(g["col"].max())), "centroid": c.tolist(), "t_s": t,
                       "velocity_px_s": vel.tolist(), "range_m": float(g["range"].mean()),
                       "radial_mps": float(g["velocity"].mean()), "points": len(g)})
    return tracks


def _box_pixels(tr: dict, t_next_s: float, frame_s: float, p: TrackParams, rows: np.ndarray,
                cols: np.ndarray) -> np.ndarray:
    """Bonded pixels of a track's predicted box at ``t_next_s`` (mid next frame) as a (rows x cols) mask."""
    dt = max(0.0, t_next_s - tr["t_s"])
    vr, vc = tr["velocity_px_s"]
    cr, cc = tr["centroid"]
    # an object at range r approaching at v grows by r / (r + v dt) in angle
    grow = tr["range_m"] / max(1e-3, tr["range_m"] + tr["radial_mps"] * dt)
    half_r = 0.5 * (tr["rows"][1] - tr["rows"][0]) * max(1.0, grow)
    half_c = 0.5 * (tr["cols"][1] - tr["cols"][0]) * max(1.0, grow)
    pr = p.pad_px + abs(vr) * frame_s
    pc = p.pad_px + abs(vc) * frame_s
    r0, r1 = cr + vr * dt - half_r - pr, cr + vr * dt + half_r + pr
    c0, c1 = cc + vc * dt - half_c - pc, cc + vc * dt + half_c + pc
    return ((rows >= r0) & (rows <= r1))[:, None] & ((cols >= c0) & (cols <= c1))[None, :]


def plan_track(request: ScanRequest, optics: FpsaOptics, frame_index: int, history: Sequence,
               params: TrackParams) -> FramePlan:
    """The next frame's pixels (dense boxes first, row by row, then the survey slice) and its trade."""
    p = params
    rows, cols = selected_rows(request, optics), selected_cols(request, optics)
    shape = (optics.rows, optics.cols)
    budget = frame_budget(history, p)
    frame_s = 1.0 / p.frame_rate_hz
    tracks = _tracks(history, p, shape) if history else []
    mask = np.zeros((rows.size, cols.size), bool)
    if tracks:
        t_next = history[-1].start_s + frame_s * 1.5   # middle of the frame after the newest
        for tr in tracks:
            mask |= _box_pixels(tr, t_next, frame_s, p, rows, cols)
    dense = np.argwhere(mask)
    dense_cap = budget - max(1, int(p.survey_share * budget)) if len(dense) else 0
    stride = 1
    while len(dense) and len(dense[::stride]) > dense_cap:
        stride += 1
    dense = dense[::stride]
    dense_px = np.stack([rows[dense[:, 0]], cols[dense[:, 1]]], axis=1) if len(dense) else np.zeros((0, 2), np.int64)
    order = survey_order(request, optics, p.step)
    cursor = int(history[-1].trade.get("survey_next", 0)) if history else 0
    n_survey = max(0, min(len(order), budget - len(dense_px)))
    take = (cursor + np.arange(n_survey)) % len(order)
    survey = order[take]
    if len(dense_px):   # a survey pixel inside a box is already scanned
        if len(survey):
            inbox = mask[np.searchsorted(rows, survey[:, 0]), np.searchsorted(cols, survey[:, 1])]
            survey = survey[~np.asarray(inbox, bool)]
    pixels = np.concatenate([dense_px, survey]).astype(np.int64)
    revisit = len(order) / max(1, n_survey)
    trade = {"pattern": "track", "frame_rate_hz": p.frame_rate_hz, "budget_pixels": budget,
             "seconds_per_pixel": seconds_per_pixel(history, p), "pixels": len(pixels),
             "survey_pixels": len(survey), "survey_grid": len(order),
             "survey_revisit_frames": revisit, "survey_revisit_s": revisit / p.frame_rate_hz,
             "dense_pixels": len(dense_px), "dense_area_pixels": int(mask.sum()), "dense_stride": stride,
             "survey_next": int((cursor + n_survey) % len(order)), "tracks": tracks}
    return FramePlan(pixels, trade)


def track_planner(request: ScanRequest, optics: FpsaOptics, params: TrackParams):
    """The ``Planner`` of a stream with ``pattern = "track"``."""
    return lambda k, history: plan_track(request, optics, k, history, params)
