"""The range and pointing fits on synthetic measurements generated from known truths (issue 13 item 2).

The synthetic data follow the physics of the module docstrings, written out here independently:
a chirp linearized against delay tau_used through a true MZI of tau_true ranges R as
(tau_used / tau_true) (R + z0); a point of pixel (row, col) lies along the TRUE pointing's ray at the
ray's intersection with the known surface.
"""

import math

import numpy as np
import pytest

from lidard.config import load_profile
from lidard.instrument.calibration.pointing import (
    Surface, fit_pointing, parse_geometry, scan_pixels)
from lidard.instrument.calibration.range import CalibrationRefused, PlateMeasurement, fit_range
from lidard.physics.optics import Pointing

TAU_NOM = 200e-9


def _plates(known, tau_true, z0, sem_m, rng, tau_used=TAU_NOM, n=30):
    out = []
    for d in known:
        raw = tau_used / tau_true * (d + z0) + rng.normal(0.0, sem_m)
        out.append(PlateMeasurement(known_m=d, known_range_m=d, raw_range_m=raw, sem_m=sem_m,
                                    pixel_std_m=sem_m * math.sqrt(n), n=n, delay_s=tau_used))
    return out


def test_range_fit_recovers_delay_and_zero_within_their_errors():
    rng = np.random.default_rng(3)
    tau_true, z0 = TAU_NOM * 1.007, 0.043
    fit = fit_range(_plates([0.8, 1.1, 1.4, 1.7], tau_true, z0, 20e-6, rng), TAU_NOM)
    assert abs(fit.delay_s - tau_true) < 4 * fit.delay_stderr_s
    assert abs(fit.zero_offset_m - z0) < 4 * fit.zero_offset_stderr_m
    assert fit.zero_offset_stderr_m < 2e-4 and fit.delay_stderr_s / tau_true < 1e-4
    assert fit.scale == pytest.approx(1 / 1.007, rel=1e-4)
    assert fit.dof == 2 and fit.p_value > 1e-3


def test_range_fit_combines_measurements_under_different_linearizations():
    # a plate measured before a first calibration (tau_used = nominal) and after it (tau_used = 201 ns)
    rng = np.random.default_rng(4)
    tau_true, z0 = 201.3e-9, -0.02
    ms = _plates([0.8, 1.2], tau_true, z0, 10e-6, rng) + _plates([1.0, 1.5], tau_true, z0, 10e-6, rng, tau_used=201e-9)
    fit = fit_range(ms, TAU_NOM)
    assert fit.delay_s == pytest.approx(tau_true, rel=5e-5)
    assert fit.zero_offset_m == pytest.approx(z0, abs=1e-4)


def test_range_fit_refuses_a_plate_at_the_wrong_known_distance_and_names_it():
    rng = np.random.default_rng(5)
    ms = _plates([0.8, 1.1, 1.4], TAU_NOM * 1.005, 0.03, 20e-6, rng)
    wrong = PlateMeasurement(**{**ms[1].as_dict(), "known_m": 1.15, "known_range_m": 1.15})
    with pytest.raises(CalibrationRefused, match=r"measurement #2 \(known_m=1.15\)") as e:
        fit_range([ms[0], wrong, ms[2]], TAU_NOM)
    assert "chi-square" in str(e.value) and "three plates cannot tell which one is wrong" in str(e.value)


def test_range_fit_with_four_plates_names_the_one_whose_removal_makes_the_others_agree():
    rng = np.random.default_rng(9)
    ms = _plates([0.8, 1.1, 1.4, 1.7], TAU_NOM * 0.996, -0.01, 20e-6, rng)
    wrong = PlateMeasurement(**{**ms[3].as_dict(), "known_m": 1.75, "known_range_m": 1.75})   # an END plate
    with pytest.raises(CalibrationRefused, match=r"measurement #4 \(known_m=1.75\).*without it the others agree"):
        fit_range([*ms[:3], wrong], TAU_NOM)


def test_range_fit_needs_two_distances():
    rng = np.random.default_rng(6)
    with pytest.raises(CalibrationRefused, match="2 different known distances"):
        fit_range(_plates([1.0, 1.0], TAU_NOM, 0.0, 1e-5, rng), TAU_NOM)
    two = fit_range(_plates([0.9, 1.3], TAU_NOM, 0.0, 1e-5, rng), TAU_NOM)
    assert two.dof == 0 and math.isnan(two.p_value) and not two.residuals()["checked"]


def test_surface_distances():
    pts = np.array([[0.0, 0.0, 1.0], [0.0, 0.3, 1.0]])
    assert Surface("sphere", (0, 0, 1.2), 0.1, "s").distance(pts) == pytest.approx([0.1, math.hypot(0.3, 0.2) - 0.1])
    assert Surface("plane", (0, 0, 1.1), (0, 0, -2.0), "p").distance(pts) == pytest.approx([0.1, 0.1])


OPTICS = load_profile("fpsa128").optics()
SPHERES = [Surface("sphere", (x, y, 1.0), 0.035, f"s{i}")
           for i, (x, y) in enumerate([(0, 0), (0.09, 0.09), (-0.09, 0.09), (0.09, -0.09), (-0.09, -0.08)])]


def _ray_sphere(d, c, r):
    b = d @ np.asarray(c)
    disc = b * b - (np.dot(c, c) - r * r)
    return np.where(disc > 0, b - np.sqrt(np.clip(disc, 0, None)), np.nan)


def _sphere_points(truth, noise_m, rng):
    px = scan_pixels(OPTICS, SPHERES)
    d = OPTICS.with_pointing(truth).directions(px[:, 0], px[:, 1])
    t = np.stack([_ray_sphere(d, s.a, s.b) for s in SPHERES], axis=1)
    rng_m = np.nanmin(np.where(np.isnan(t), np.inf, t), axis=1)
    hit = np.isfinite(rng_m)
    return px[hit, 0], px[hit, 1], rng_m[hit] + rng.normal(0, noise_m, hit.sum())


def test_pointing_fit_recovers_a_known_pointing_within_its_noise():
    truth = Pointing(focal_scale=1.008, decentre_px=(0.7, -0.4), rotation_rad=math.radians(0.35), k1=0.15)
    rng = np.random.default_rng(7)
    rows, cols, r = _sphere_points(truth, 100e-6, rng)
    fit = fit_pointing(OPTICS, rows, cols, r, SPHERES, noise_m=100e-6)
    got = fit.pointing
    err = fit.stderr
    assert abs(got.focal_scale - truth.focal_scale) < 4 * err["focal_scale"] + 1e-5
    assert abs(got.decentre_px[0] - 0.7) < 4 * err["decentre_x_px"] + 1e-3
    assert abs(got.decentre_px[1] + 0.4) < 4 * err["decentre_y_px"] + 1e-3
    assert abs(got.rotation_rad - truth.rotation_rad) < 4 * err["rotation_rad"] + 1e-5
    assert abs(got.k1 - truth.k1) < 4 * err["k1"] + 1e-3
    assert err["decentre_x_px"] < 0.1 and err["focal_scale"] < 1e-3
    # residual at the noise: 100 um rms along the ray, a bit less onto a curved surface
    assert 50e-6 < fit.rms_m < 130e-6
    assert fit.rms_px == pytest.approx(fit.rms_m / 1.0 * OPTICS.focal_m / OPTICS.pitch_m, rel=0.1)
    # with the nominal model the same points are mm off their spheres: the fit did something
    nominal = OPTICS.directions(rows, cols) * r[:, None]
    off = np.min(np.abs(np.stack([s.distance(nominal) for s in SPHERES], axis=1)), axis=1)
    assert np.sqrt(np.mean(off ** 2)) > 10 * fit.rms_m


def test_pointing_fit_refuses_a_wrong_geometry_and_too_few_points():
    truth = Pointing(decentre_px=(0.5, 0.0))
    rng = np.random.default_rng(8)
    rows, cols, r = _sphere_points(truth, 100e-6, rng)
    moved = [*SPHERES[:4], Surface("sphere", (-0.09, -0.08, 1.006), 0.035, "s4")]   # one sphere 6 mm off
    with pytest.raises(CalibrationRefused, match=r"s4: only \d+ of its \d+ points lie within"):
        fit_pointing(OPTICS, rows, cols, r, moved, noise_m=100e-6)
    # all points off by more than the noise allows (range noise 6x what the range calibration measured)
    with pytest.raises(CalibrationRefused, match="RMS point-to-surface residual"):
        fit_pointing(OPTICS, rows, cols, r + rng.normal(0, 600e-6, len(r)), SPHERES, noise_m=100e-6)
    with pytest.raises(CalibrationRefused, match=r"points lie within .* \(need 40\)"):
        fit_pointing(OPTICS, rows[:20], cols[:20], r[:20], SPHERES[:1], noise_m=100e-6)


def test_geometry_errors_name_the_entry():
    with pytest.raises(CalibrationRefused, match=r"sphere\[1\].radius"):
        parse_geometry({"sphere": [{"centre": [0, 0, 1], "radius": 0.1}, {"centre": [0, 0, 1], "radius": -1}]})
    with pytest.raises(CalibrationRefused, match=r"plane\[0\].normal"):
        parse_geometry({"plane": [{"point": [0, 0, 1], "normal": [0, 0, 0]}]})
    with pytest.raises(CalibrationRefused, match="unknown key"):
        parse_geometry({"spheres": []})


def test_pointing_fit_uses_planes_with_spheres_and_refuses_a_plane_alone():
    truth = Pointing(focal_scale=0.995, decentre_px=(-0.6, 0.3), rotation_rad=-0.004, k1=-0.1)
    wall = Surface("plane", (0.0, 0.0, 1.3), (0.0, 0.0, -1.0), "wall")
    rng = np.random.default_rng(12)
    px = scan_pixels(OPTICS, [*SPHERES, wall])
    assert len(px) == len(OPTICS.bonded_pixels())              # a plane's extent is unknown: whole frame
    px = px[::7]
    d = OPTICS.with_pointing(truth).directions(px[:, 0], px[:, 1])
    t_sph = np.stack([_ray_sphere(d, s.a, s.b) for s in SPHERES], axis=1)
    t = np.fmin(np.nanmin(np.where(np.isnan(t_sph), np.inf, t_sph), axis=1), 1.3 / d[:, 2])
    r = t + rng.normal(0, 100e-6, len(t))
    fit = fit_pointing(OPTICS, px[:, 0], px[:, 1], r, [*SPHERES, wall], noise_m=100e-6)
    assert abs(fit.pointing.decentre_px[0] + 0.6) < 4 * fit.stderr["decentre_x_px"] + 1e-3
    assert abs(fit.pointing.focal_scale - 0.995) < 4 * fit.stderr["focal_scale"] + 1e-5
    assert {s["name"]: s["points"] for s in fit.per_surface}["wall"] > 1000
    # a wall perpendicular to the axis alone says almost nothing about where the beams point
    flat = np.isinf(np.nanmin(np.where(np.isnan(t_sph), np.inf, t_sph), axis=1))
    with pytest.raises(CalibrationRefused, match="do not fix the model"):
        fit_pointing(OPTICS, px[flat, 0], px[flat, 1], r[flat], [wall], noise_m=100e-6)
