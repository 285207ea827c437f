"""Range and pointing calibration end to end: REST -> worker -> instrument -> simulated bench (issue 13).

The bench's monitor MZI is 201 ns while the daemon's configuration says 200 ns (tests.helpers.split_bench:
with the bench's own ``[sim.tolerances]`` switched off, so that the truth is known exactly). Raw ranges
are then short by tau_nom / tau_true (R_raw = 0.995 R: -5 mm at 1 m); the range calibration must find
the 201 ns from plates at known distances alone, and the next scan must range the plate right.
The last test runs both calibrations on a bench with its own hidden tolerances (whatever they are)
and checks the outcome only: plates and spheres measured right afterwards.
"""

import contextlib
import io
import json
import threading

import numpy as np
import pytest

from lidard.config import load_config
from lidard.instrument.calibration import AppliedCalibrations, run_pointing_calibration, run_range_calibration
from lidard.instrument.calibration.range import plate_scene
from lidard.store import Store
from tests.helpers.api import app_client
from tests.helpers.split_bench import open_split

pytestmark = pytest.mark.slow  # benches with hidden tolerances, range and pointing calibrations (~1-3 min)

TAU_TRUE = 201e-9
ROI = {"pattern": "roi", "rows": [60, 68], "cols": [60, 68], "max_range_m": 2.0, "formats": ["npz"]}
SPHERES = [(0.0, 0.0), (0.09, 0.09), (-0.09, 0.09), (0.09, -0.09), (-0.09, -0.08)]
GEOMETRY = {"sphere": [{"centre": [x, y, 1.0], "radius": 0.035, "name": f"s{i}"} for i, (x, y) in enumerate(SPHERES)]}


@pytest.fixture(scope="module")
def inst():
    daemon_cfg = load_config("config/sim.toml")
    bench_cfg = load_config("config/sim.toml", environ={"LIDARD__MONITOR__DELAY_S": str(TAU_TRUE),
                                                        "LIDARD__SIM__TOLERANCES__ENABLED": "false"})
    inst = open_split(daemon_cfg, bench_cfg)
    inst.nominal_linearization = inst.linearize()     # one ILC run (seconds) shared by the tests
    yield inst
    inst.close()


@contextlib.contextmanager
def _daemon(inst, tmp_path):
    """The daemon's app on ``inst`` with a store that already holds the nominal-delay linearization."""
    inst.use_calibrations(AppliedCalibrations())
    st = Store(tmp_path)
    st.save_calibration(inst.nominal_linearization)
    st.close()
    with app_client(tmp_path, inst, load_config("config/sim.toml"), close_instrument=False) as client:
        yield client


def _place(client, scene):
    assert client.put("/sim/scene", json=scene).status_code == 200


def _scan(client, tmp_path):
    r = client.post("/scans", json=ROI)
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    with client.stream("GET", f"/scans/{sid}/events") as events:
        assert any(ln.startswith("event: end") for ln in events.iter_lines() if ln)
    rec = client.get(f"/scans/{sid}").json()
    pts = np.load(io.BytesIO(client.get(f"/scans/{sid}/points", params={"format": "npz"}).content))["points"]
    sidecar = json.loads((tmp_path / "scans" / sid / "scan.npz.json").read_text())
    return rec, pts, sidecar


def _plate_error_m(pts, d):
    good = pts["valid"] == 1
    assert good.sum() >= 20
    # the plate plane z = d: the range along each ray is d / d_z, d_z = z / range
    return float(np.mean(pts["range"][good] - d * pts["range"][good] / pts["z"][good]))


def test_range_calibration_finds_the_true_delay_and_refuses_a_wrong_plate(inst, tmp_path):
    with _daemon(inst, tmp_path) as client:
        _place(client, plate_scene(1.25))
        rec, pts, sidecar = _scan(client, tmp_path)
        # uncalibrated: said, and the raw range scale is off by tau_nom / tau_true
        assert rec["calibrated"] == {"range": False, "pointing": False, "linearization": True}
        assert sidecar["calibrated"]["range"] is False and sidecar["range_calibration_id"] is None
        assert _plate_error_m(pts, 1.25) == pytest.approx(1.25 * (200 / 201 - 1), abs=0.5e-3)

        # a plate entered at the wrong known distance: refused, named, the plates kept
        for d, entered in ((0.8, 0.8), (1.1, 1.15), (1.4, 1.4)):
            _place(client, plate_scene(d))
            r = client.post("/calibration/range/plates", json={"known_m": entered})
            assert r.status_code == 201, r.text
        r = client.post("/calibration/range/fit")
        assert r.status_code == 422
        assert "measurement #2 (known_m=1.15)" in r.json()["detail"]
        plates = client.get("/calibration/range/plates").json()
        assert [p["known_m"] for p in plates] == [0.8, 1.15, 1.4]

        # drop it, measure it again at the right distance, fit
        assert client.delete(f"/calibration/range/plates/{plates[1]['id']}").json() == {"removed": 1}
        _place(client, plate_scene(1.1))
        assert client.post("/calibration/range/plates", json={"known_m": 1.1}).status_code == 201
        r = client.post("/calibration/range/fit")
        assert r.status_code == 201, r.text
        cal = r.json()
        f = cal["fitted"]
        assert abs(f["delay_s"] - TAU_TRUE) < max(4 * f["delay_stderr_s"], 2e-4 * TAU_TRUE)
        assert abs(f["zero_offset_m"]) < max(4 * f["zero_offset_stderr_m"], 1e-4)   # the bench has none yet
        assert cal["residuals"]["dof"] == 1 and len(cal["inputs"]["measurements"]) == 3
        assert client.get("/calibration/range/plates").json() == []
        assert client.get(f"/calibration/records/{cal['id']}").json()["kind"] == "range"

        # the next scan re-linearizes against the fitted delay and ranges the plate right
        _place(client, plate_scene(1.25))
        rec, pts, sidecar = _scan(client, tmp_path)
        assert rec["range_calibration_id"] == cal["id"] and rec["calibrated"]["range"] is True
        assert sidecar["range_calibration_id"] == cal["id"]
        assert sidecar["geometry"]["monitor_delay_s"] == pytest.approx(f["delay_s"])
        assert abs(_plate_error_m(pts, 1.25)) < 0.1e-3
        lin = client.get("/calibration/records", params={"kind": "linearization"}).json()
        assert len(lin) == 2 and lin[0]["fitted"]["mzi_delay_s"] == pytest.approx(f["delay_s"])
        assert lin[1]["fitted"]["mzi_delay_s"] == 200e-9


def test_pointing_calibration_needs_range_first_then_fits_the_spheres(inst, tmp_path):
    with _daemon(inst, tmp_path) as client:
        r = client.post("/calibration/pointing", json={"geometry": GEOMETRY})
        assert r.status_code == 422 and "no range calibration yet" in r.json()["detail"]
        for d in (0.8, 1.4):
            _place(client, plate_scene(d))
            assert client.post("/calibration/range/plates", json={"known_m": d}).status_code == 201
        assert client.post("/calibration/range/fit").status_code == 201
        _place(client, {"name": "spheres", "target": [
            {"kind": "sphere", "center": [x, y, 1.0], "radius": 0.035, "reflectivity": 0.5} for x, y in SPHERES]})
        r = client.post("/calibration/pointing", json={"geometry": GEOMETRY})
        assert r.status_code == 201, r.text
        rec = r.json()
        f, res = rec["fitted"], rec["residuals"]
        # the bench's pointing is nominal (until it hides its own): the fit must find nominal within its errors
        assert abs(f["focal_scale"] - 1) < 4 * f["stderr"]["focal_scale"] + 1e-4
        assert max(abs(v) for v in f["decentre_px"]) < 0.02
        assert abs(f["rotation_rad"]) < 4 * f["stderr"]["rotation_rad"] + 1e-5
        assert res["rms_mm"] < 0.2 and res["points"] > 1000 and len(res["per_surface"]) == 5
        # pixels: residual / range x f / pitch, the spheres ~1 m away
        o = inst.optics
        assert res["rms_px"] == pytest.approx(res["rms_mm"] * 1e-3 / 0.97 * o.focal_m / o.pitch_m, rel=0.1)
        _place(client, plate_scene(1.0))
        scan, _, sidecar = _scan(client, tmp_path)
        assert scan["calibrated"] == {"range": True, "pointing": True, "linearization": True}
        assert sidecar["pointing_calibration_id"] == rec["id"]
        bad = dict(GEOMETRY, sphere=[{"centre": [0, 0, 1.0], "radius": -1}])
        assert client.post("/calibration/pointing", json={"geometry": bad}).status_code == 422


def test_benchmark_entry_points_calibrate_an_embedded_instrument(inst):
    inst.use_calibrations(AppliedCalibrations())          # what the REST tests left applied: gone
    lin = inst.nominal_linearization
    assert lin.meta["mzi_delay_s"] == 200e-9
    run = run_range_calibration(inst, [0.8, 1.1, 1.4], linearization=lin)
    assert run.fit.delay_s == pytest.approx(TAU_TRUE, rel=2e-4) and len(run.measurements) == 3
    assert inst.monitor_delay_s() == run.fit.delay_s
    assert run.linearization.meta["mzi_delay_s"] == run.fit.delay_s        # re-linearized against it
    prun = run_pointing_calibration(inst, GEOMETRY, linearization=run.linearization,
                                    noise_m=run.fit.pixel_std_m)
    assert prun.linearization is run.linearization                          # the delay did not change
    assert prun.fit.rms_m < 2 * run.fit.pixel_std_m and inst.applied.pointing == prun.fit.pointing
    assert inst.applied.range_id is not None and inst.applied.delay_s == run.fit.delay_s


CHECK_SPHERES = [(0.05, -0.04, 1.2, 0.04), (-0.06, 0.05, 0.9, 0.03), (0.08, 0.07, 1.1, 0.03)]


def _sphere_rms_m(pts, spheres):
    good = pts[(pts["valid"] == 1) & (pts["return_index"] == 0)]
    xyz = np.stack([good["x"], good["y"], good["z"]], axis=1).astype(np.float64)
    d = np.min(np.abs(np.stack([np.linalg.norm(xyz - np.array(s[:3]), axis=1) - s[3] for s in spheres], axis=1)),
               axis=1)
    on = d < 0.02                    # the points of the spheres (nothing else is in the scene)
    assert on.sum() > 300
    return float(np.sqrt(np.mean(d[on] ** 2)))


def test_both_calibrations_on_a_bench_with_its_own_hidden_tolerances():
    """The outcome a lab wants, whatever the bench drew: after the range and pointing calibrations a
    plate is ranged right and other spheres lie on their known surfaces (x, y, z, not only range)."""
    from lidard.instrument import ScanRequest, open_instrument
    from lidard.instrument.calibration.pointing import Surface, scan_pixels
    cfg = load_config("config/sim.toml", environ={"LIDARD__SIM__TOLERANCES__SEED": "5"})
    inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    try:
        run = run_range_calibration(inst, [0.8, 1.1, 1.4])
        prun = run_pointing_calibration(inst, GEOMETRY, linearization=run.linearization, noise_m=run.fit.pixel_std_m)
        lin = prun.linearization
        inst.set_scene(plate_scene(1.25))
        res = inst.run_scan(ScanRequest(**{k: v for k, v in ROI.items() if k != "formats"}), lambda p: None,
                            threading.Event(), lin)
        assert abs(_plate_error_m(res.points, 1.25)) < 0.1e-3
        inst.set_scene({"target": [{"kind": "sphere", "center": list(s[:3]), "radius": s[3], "reflectivity": 0.5}
                                   for s in CHECK_SPHERES]})
        px = scan_pixels(inst.optics, [Surface("sphere", s[:3], s[3], "c") for s in CHECK_SPHERES])
        res = inst.run_scan(ScanRequest(pattern="pixels", pixels=tuple(map(tuple, px.tolist())), max_range_m=2.0),
                            lambda p: None, threading.Event(), lin)
        # A pixel whose beam footprint straddles a silhouette (issue 15: the bench reports it mixed)
        # ranges the limb its footprint sees and places it along the central ray, up to a footprint
        # radius (~3 mm) off the surface: the instrument's edge blur, not a pointing error. Scored
        # on the other pixels, which are most of them.
        pts = res.points
        mixed = inst._on_close.__self__.mixed_pixels(pts["row"], pts["col"])
        assert mixed.any() and mixed.mean() < 0.5
        assert _sphere_rms_m(pts[~mixed], CHECK_SPHERES) < 2 * run.fit.pixel_std_m + 50e-6
    finally:
        inst.close()
