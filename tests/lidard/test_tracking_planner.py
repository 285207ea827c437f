"""The track planner as a pure function of the last frames' points (no bench)."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import load_config
from lidard.instrument.stream import Frame
from lidard.instrument.types import POINT_DTYPE, ScanRequest
from lidard.instrument.plan import ScanPlanError, plan
from lidard.instrument.tracking import TrackParams, plan_track, survey_order

REQ = ScanRequest(pattern="track", rows=(16, 112), cols=(16, 112), max_range_m=3.0)
PIXEL_S = 243e-6


@pytest.fixture(scope="module")
def optics():
    cfg = load_config("config/sim.toml")
    return cfg.load_profile().optics(cfg.lens, cfg.chirp.wavelength_m)


def _points(rows, cols, rng, t, vel=0.0):
    p = np.zeros(len(rows), POINT_DTYPE)
    p["row"], p["col"], p["range"], p["t"], p["velocity"], p["valid"] = rows, cols, rng, t, vel, 1
    return p


def _frame(index, pixels, pts, start_s, trade=None):
    return Frame(index, pts, np.asarray(pixels), len(pixels), start_s, 0.05, 0.0, PIXEL_S, trade=trade or {})


def _wall_and_object(optics, index, start_s, obj_cols, obj_range=1.0, obj_vel=0.0, prev=None):
    """A survey frame: the wall at 2.5 m on the survey grid, the object's pixels at obj_range."""
    grid = survey_order(REQ, optics, 4)
    bonded = np.array([r for r in optics.bonded_rows if 60 <= r < 68])
    orr, occ = np.meshgrid(bonded, np.asarray(obj_cols), indexing="ij")
    obj = _points(orr.ravel(), occ.ravel(), obj_range, start_s + 0.02, obj_vel)
    keep = ~np.isin(grid[:, 0] * 1000 + grid[:, 1], orr.ravel() * 1000 + occ.ravel())
    wall = _points(grid[keep, 0], grid[keep, 1], 2.5, start_s + 0.02)
    pts = np.concatenate([wall, obj])
    return _frame(index, np.stack([pts["row"], pts["col"]], 1), pts, start_s,
                  trade={"survey_next": 0} if prev is None else prev)


def test_budget_follows_frame_rate_and_measured_pixel_time(optics):
    p = TrackParams(frame_rate_hz=10, pixel_s=PIXEL_S)
    fp = plan_track(REQ, optics, 0, [], p)
    assert fp.trade["budget_pixels"] == int(0.95 / 10 / (2 * PIXEL_S))        # first guess: 2 x the chirp's pixel
    assert len(fp.pixels) == fp.trade["budget_pixels"] == fp.trade["survey_pixels"]
    # two frames 0.1 s apart with 150 pixels in the first: 0.1 / 150 s per pixel measured
    h = [_frame(0, np.zeros((150, 2), int), np.zeros(0, POINT_DTYPE), 0.0, {"survey_next": 0}),
         _frame(1, np.zeros((150, 2), int), np.zeros(0, POINT_DTYPE), 0.1, {"survey_next": 150})]
    fp = plan_track(REQ, optics, 2, h, p)
    assert fp.trade["seconds_per_pixel"] == pytest.approx(0.1 / 150)
    assert fp.trade["budget_pixels"] == int(0.95 / 10 / (0.1 / 150))
    p20 = TrackParams(frame_rate_hz=20, pixel_s=PIXEL_S)
    assert plan_track(REQ, optics, 2, h, p20).trade["budget_pixels"] == int(0.95 / 20 / (0.1 / 150))


def test_survey_revisits_the_whole_grid(optics):
    """Frames without anything of interest survey consecutive slices of the coarse grid: after
    ceil(grid / budget) frames every grid pixel was visited."""
    p = TrackParams(frame_rate_hz=10, pixel_s=PIXEL_S)
    grid = {tuple(x) for x in survey_order(REQ, optics, 4)}
    seen, hist = set(), []
    n = None
    for k in range(40):
        fp = plan_track(REQ, optics, k, hist, p)
        n = n or -(-len(grid) // len(fp.pixels))
        seen |= {tuple(x) for x in fp.pixels}
        assert fp.trade["dense_pixels"] == 0
        hist = [_frame(k, fp.pixels, _points(fp.pixels[:, 0], fp.pixels[:, 1], 2.5, 0.1 * k), 0.1 * k, fp.trade)]
        if len(seen) == len(grid):
            break
    assert seen == grid
    assert k + 1 == n
    assert fp.trade["survey_revisit_frames"] == pytest.approx(len(grid) / len(fp.pixels))


def test_object_before_the_wall_is_tracked_and_predicted_sideways(optics):
    """An object 4 columns further each 0.1 s (40 px/s): the planner measures that motion and puts the
    next frame's dense box where the object will be, not where it was."""
    p = TrackParams(frame_rate_hz=10, pixel_s=PIXEL_S)
    f0 = _wall_and_object(optics, 0, 0.0, range(50, 58))
    f1 = _wall_and_object(optics, 1, 0.1, range(54, 62), prev={"survey_next": 10})
    fp = plan_track(REQ, optics, 2, [f0, f1], p)
    (tr,) = fp.trade["tracks"]
    assert tr["velocity_px_s"][1] == pytest.approx(40.0, rel=1e-6)
    assert tr["velocity_px_s"][0] == pytest.approx(0.0, abs=1e-9)
    dense = fp.pixels[:fp.trade["dense_pixels"]]
    assert fp.trade["dense_pixels"] > 0 and fp.trade["survey_pixels"] > 0
    # predicted at the middle of frame 2 (t = 0.25 s): centroid col 57.5 + 40 x (0.25 - 0.12) = 62.7;
    # box half-width 3.5 + pad 2 + 4 px of motion per frame
    c = 57.5 + 40 * (0.25 - 0.12)
    assert dense[:, 1].min() >= np.floor(c - 9.5) and dense[:, 1].max() <= np.ceil(c + 9.5)
    assert dense[:, 1].max() >= 68      # ahead of the object's last position (cols 54..61)
    assert len(fp.pixels) <= fp.trade["budget_pixels"]
    assert len(np.unique(fp.pixels, axis=0)) == len(fp.pixels)


def test_moving_return_at_wall_range_is_tracked_by_radial_velocity(optics):
    p = TrackParams(frame_rate_hz=10, pixel_s=PIXEL_S)
    f0 = _wall_and_object(optics, 0, 0.0, range(70, 76), obj_range=2.5, obj_vel=-1.0)
    fp = plan_track(REQ, optics, 1, [f0], p)
    assert len(fp.trade["tracks"]) == 1 and fp.trade["tracks"][0]["radial_mps"] == pytest.approx(-1.0)
    still = _wall_and_object(optics, 0, 0.0, range(70, 76), obj_range=2.5, obj_vel=0.0)
    assert plan_track(REQ, optics, 1, [still], p).trade["tracks"] == []


def test_dense_boxes_thinned_to_their_share(optics):
    """Boxes larger than the budget are scanned every stride-th pixel and the survey keeps its share."""
    p = TrackParams(frame_rate_hz=40, pixel_s=PIXEL_S)
    f0 = _wall_and_object(optics, 0, 0.0, range(30, 90))
    fp = plan_track(REQ, optics, 1, [f0], p)
    t = fp.trade
    assert t["dense_stride"] > 1
    assert t["dense_pixels"] <= t["budget_pixels"] - int(p.survey_share * t["budget_pixels"])
    assert t["dense_area_pixels"] > t["dense_pixels"]


def test_bad_parameters_and_single_scan_refused(optics):
    with pytest.raises(ValueError, match="frame_rate_hz"):
        TrackParams(frame_rate_hz=0)
    with pytest.raises(ValueError, match="survey_share"):
        TrackParams(survey_share=1.0)
    with pytest.raises(ScanPlanError, match="track"):
        plan(REQ, optics)
