"""benchmarks/tolerances.py's scorer (the hook calibrated scans go through) and its variants,
checked on hand-made points against a hand-made scene (no bench)."""

import numpy as np
import pytest

from benchmarks.tolerances import TOLERANCES, expected_range_rms, score_points, variants
from lidard.instrument.types import POINT_DTYPE
from sim_devices.world.scene import Scene
from sim_devices.world.tolerances import BenchTruth

WALL = Scene.from_dict({"target": [{"kind": "plane", "point": [0, 0, 1.0], "normal": [0, 0, -1]}]})


def _points(xyz, rng, valid=None):
    p = np.zeros(len(xyz), POINT_DTYPE)
    p["x"], p["y"], p["z"] = np.asarray(xyz).T
    p["range"] = rng
    p["valid"] = 1 if valid is None else valid
    return p


def test_scores_split_range_from_pointing():
    # two beams truly at 1.000 m on the wall; ranged 2 mm long, and placed 3 mm too far along z
    # by a (wrong) pointing model; a third point flagged invalid is not scored
    pts = _points([[0, 0, 1.003], [0.1, 0, 1.003], [0, 0, 5.0]], [1.002, 1.002, 9.0], valid=[1, 1, 0])
    s = score_points(pts, WALL, ground_truth=lambda r, c: np.full(len(r), 1.0))
    assert s["points"] == 2
    # (points are float32: ~1e-7 m)
    assert s["rms_range_m"] == pytest.approx(0.002, abs=1e-6) and s["mean_range_m"] == pytest.approx(0.002, abs=1e-6)
    assert s["rms_surface_m"] == pytest.approx(0.003, abs=1e-6)
    # without the bench's truth: along each point's own ray (|p| - range to the wall on that ray)
    # the ray through p meets the wall z = 1 at |p| / 1.003
    own = score_points(pts, WALL)
    r = np.linalg.norm([[0, 0, 1.003], [0.1, 0, 1.003]], axis=1)
    assert own["rms_range_m"] == pytest.approx(np.sqrt(np.mean((r * (1 - 1 / 1.003)) ** 2)), abs=1e-6)


def test_expected_range_error_of_delay_and_zero_offset():
    # true delay 1 % long, z0 = 2 cm: a surface at d reads (d + z0) / 1.01
    t = BenchTruth(202e-9, 0.02, nominal_mzi_delay_s=200e-9)
    d = np.array([0.8, 0.9])
    want = np.sqrt(np.mean(((d + 0.02) / 1.01 - d) ** 2))
    assert expected_range_rms(t, d) == pytest.approx(want, rel=1e-12)


def test_each_sensitivity_bench_has_one_tolerance_on():
    v = variants()
    assert v["nominal bench"] == {"LIDARD__SIM__TOLERANCES__ENABLED": "false"}
    for name in TOLERANCES:
        env = v[f"{name} at its bound"]
        zeros = {k for k, val in env.items() if val == "0"}
        assert zeros == {f"LIDARD__SIM__TOLERANCES__{o.upper()}" for o in TOLERANCES if o != name}
        assert env["LIDARD__SIM__TOLERANCES__DRAW"] == "false"


def test_mixed_pixels_are_left_out_and_counted():
    # three beams on the wall; the third's footprint crosses an outline (its return blends two surfaces)
    pts = _points([[0, 0, 1.0], [0.1, 0, 1.0], [0.2, 0, 1.3]], [1.0, 1.0, 1.3])
    pts["row"] = [1, 2, 3]
    s = score_points(pts, WALL, ground_truth=lambda r, c: np.full(len(r), 1.0),
                     mixed=lambda r, c: np.asarray(r) == 3)
    assert s["points"] == 2 and s["mixed_pixels"] == 1 and s["rms_range_m"] == pytest.approx(0.0, abs=1e-6)
