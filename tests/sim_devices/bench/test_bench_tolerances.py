"""The bench applies its hidden truths (issue 13), checked through what the instruments see:

* the monitor fringe rate is kappa x tau_MZI with the TRUE delay (not the configured one);
* a zero offset z0 raises a return's beat by 2 z0 kappa / c, kappa the chirp rate;
* the true pointing moves where a small off-axis target appears, by the pixel shift worked out by
  hand from the pointing model's definition (rotation, decentre, focal scale, k1);
* Bench.truth() and the control command ``truth`` report what was drawn.

Each bench is built from config/sim.toml with explicit overrides (``environ=``), the random effects
off where a frequency is measured, so the comparisons are exact up to the fit.
"""

import math

import numpy as np
import pytest
from scipy.signal import hilbert

from lidard.config import load_config
from lidard.physics.constants import C_M_PER_S
from sim_devices.bench.bench import Bench, BenchControlClient
from sim_devices.digitizer.device import CaptureConfig
from sim_devices.world.scene import Scene
from tests.helpers.sim_bench import SIM_TOML, lit_bench
from tests.helpers.tolerances import NOMINAL_ENV

FS = 100e6
CAP = CaptureConfig(FS, 8000, ("beat", "mzi"), 16, 1.0)      # 80 us: the up-ramp
QUIET = {f"LIDARD__SIM__EFFECTS__{e}": "false" for e in ("NOISE", "PHASE_NOISE", "QUANTIZATION")}
OFF = {f"LIDARD__SIM__TOLERANCES__{k.upper()}": "0" for k in
       ("mzi_delay_rel", "zero_offset_m", "focal_rel", "decentre_px", "rotation_deg", "k1")}
WALL_M = 1.0


def _env(**bounds) -> dict:
    """Tolerances at their bounds (draw = false), every one not named off."""
    env = {**QUIET, **OFF, "LIDARD__SIM__TOLERANCES__DRAW": "false"}
    env.update({f"LIDARD__SIM__TOLERANCES__{k.upper()}": repr(float(v)) for k, v in bounds.items()})
    return env


def _lit_bench(environ: dict):
    scene = Scene.from_dict({"target": [{"kind": "plane", "point": [0, 0, WALL_M], "normal": [0, 0, -1],
                                         "reflectivity": 1.0}]})
    return lit_bench(environ, [[64, 64]], scene)


def _mean_freq_hz(x: np.ndarray) -> float:
    """Mean frequency over the middle of the record: slope of the analytic signal's phase."""
    x = x - x.mean()
    ph = np.unwrap(np.angle(hilbert(x)))
    t = np.arange(x.size) / FS
    mid = slice(x.size // 8, -x.size // 8)
    return float(np.polyfit(t[mid], ph[mid], 1)[0] / (2 * np.pi))


def _freqs(environ: dict) -> tuple[float, float, Bench]:
    with _lit_bench(environ) as b:
        cap = b.capture(0, 1, CAP)
    codes = cap.codes[0].astype(float)
    return _mean_freq_hz(codes[0]), _mean_freq_hz(codes[1]), b


def test_monitor_fringes_follow_the_true_mzi_delay():
    _, f_nom, b_nom = _freqs(_env())
    _, f_true, b = _freqs(_env(mzi_delay_rel=0.02))
    assert b.truth().mzi_delay_s == pytest.approx(1.02 * b.cfg.monitor.delay_s)
    assert b_nom.truth().mzi_delay_s == b.cfg.monitor.delay_s
    # fringe rate = kappa tau: with the same chirp, the ratio is the delays' ratio
    assert f_true / f_nom == pytest.approx(1.02, abs=2e-4)
    # and it is kappa x the true delay, kappa the laser's true chirp rate over the same window
    # (the slope of nu(t) of the bench's laser under this drive; a plain triangle, not linearized)
    traj = b.synthesizer.trajectory()
    t = np.arange(traj.nu_hz.size) / traj.fs_hz
    win = (t >= 10e-6) & (t < 70e-6)
    kappa = np.polyfit(t[win], traj.nu_hz[win], 1)[0]
    assert f_true == pytest.approx(kappa * b.truth().mzi_delay_s, rel=0.01)


def test_zero_offset_raises_the_beat_by_2_z0_kappa_over_c():
    z0 = 0.05
    f_nom, _, _ = _freqs(_env())
    f_z0, _, b = _freqs(_env(zero_offset_m=z0))
    assert b.truth().zero_offset_m == z0
    kappa_eff = f_nom * C_M_PER_S / (2 * WALL_M)       # the chirp rate this laser really has
    assert f_z0 - f_nom == pytest.approx(2 * z0 * kappa_eff / C_M_PER_S, rel=0.01)
    # the world's truth stays the geometric lens -> wall distance along pixel (64, 64)'s beam (eq. 4-1:
    # chip offset (27.5, -27.5) um behind f = 25 mm): no z0 in it
    off = 0.5 * 55e-6 / 25e-3
    assert b.ground_truth(np.array([64]), np.array([64]))[0] == pytest.approx(
        WALL_M * math.sqrt(1 + 2 * off * off), rel=1e-12)


# --- pointing -------------------------------------------------------------------------------------
PITCH, F = 55e-6, 25e-3
N = 128


def _target_pixel(b: Bench, direction: np.ndarray) -> tuple[float, float]:
    """Centroid (row, col) of the pixels whose beams hit a small sphere along ``direction``."""
    r_m = 1.0
    c = r_m * direction / np.linalg.norm(direction)
    b.set_scene(Scene.from_dict({"target": [{"kind": "sphere", "center": c.tolist(), "radius": 0.005}]}))
    rr, cc = np.meshgrid(np.arange(N), np.arange(N), indexing="ij")
    hit = np.isfinite(b.ground_truth(rr.ravel(), cc.ravel()))
    assert 4 <= hit.sum() <= 40, hit.sum()      # a few beams across the 10 mm ball (2.2 mm apart)
    return float(rr.ravel()[hit].mean()), float(cc.ravel()[hit].mean())


def _chip_xy(row, col):
    return (col - (N - 1) / 2) * PITCH, ((N - 1) / 2 - row) * PITCH


def _pixel(x, y):
    return (N - 1) / 2 - y / PITCH, x / PITCH + (N - 1) / 2


# A target seen by nominal pixel (row0, col0); where the true scanner sees it, by hand: the antenna
# at chip (x, y) points where the nominal one at image coordinate f (u, v) did, with (u, v) from
# the pointing model's definition (Pointing docstring), so solve for (x, y) given the target's (xt, yt).
ROW0, COL0 = 12.0, 116.0


def _expected(kind: str, value: float) -> tuple[float, float]:
    xt, yt = _chip_xy(ROW0, COL0)
    if kind == "rotation_deg":      # R(a) (x, y) = (xt, yt)  ->  (x, y) = R(-a) (xt, yt)
        a = math.radians(value)
        x, y = math.cos(a) * xt + math.sin(a) * yt, -math.sin(a) * xt + math.cos(a) * yt
    elif kind == "decentre_px":     # (x + d p, y + d p) = (xt, yt)
        x, y = xt - value * PITCH, yt - value * PITCH
    elif kind == "focal_rel":       # x / (f (1 + e)) = xt / f
        x, y = xt * (1 + value), yt * (1 + value)
    else:                           # k1: u (1 + k1 |u|^2) = ut, one fixed-point pass is plenty here
        ut, vt = xt / F, yt / F
        s = 1.0
        for _ in range(20):
            s = 1.0 / (1.0 + value * (ut * ut + vt * vt) * s * s)
        x, y = xt * s, yt * s
    return _pixel(x, y)


@pytest.mark.parametrize("kind,value", [("rotation_deg", 3.0), ("decentre_px", 4.0),
                                        ("focal_rel", 0.04), ("k1", 1.0)])
def test_true_pointing_moves_an_off_axis_target_by_the_model_shift(kind, value):
    xt, yt = _chip_xy(ROW0, COL0)
    direction = np.array([-xt / F, -yt / F, 1.0])        # eq. 4-1 for the nominal pixel
    nominal = _target_pixel(Bench(load_config(SIM_TOML, environ=_env())), direction)
    assert nominal == pytest.approx((ROW0, COL0), abs=0.35)
    moved = _target_pixel(Bench(load_config(SIM_TOML, environ=_env(**{kind: value}))), direction)
    want = _expected(kind, value)
    shift = np.subtract(want, (ROW0, COL0))
    assert np.hypot(*shift) > 1.0                         # a visible move (pixels)
    # centroids of a handful of beams: within ~1/3 pixel of the predicted place
    assert moved == pytest.approx(want, abs=0.35), (moved, want)


@pytest.mark.tolerances
def test_truth_is_reported_by_the_bench_and_its_control_socket():
    cfg = load_config(SIM_TOML)          # the marker: config/sim.toml's tolerances, on
    assert cfg.sim.tolerances.enabled
    b = Bench(cfg)
    b.start(usb="inproc", control=True)
    try:
        t = b.truth()
        assert t.zero_offset_m > 0 and t.mzi_delay_s != cfg.monitor.delay_s and not t.pointing.nominal
        client = BenchControlClient(b.endpoints()["control_port"])
        try:
            reply = client.call("truth")["truth"]
        finally:
            client.close()
        assert reply["zero_offset_m"] == t.zero_offset_m and reply["mzi_delay_s"] == t.mzi_delay_s
        assert reply["pointing"]["decentre_px"] == list(t.pointing.decentre_px)
    finally:
        b.close()


def test_the_session_default_is_a_nominal_bench():
    b = Bench(load_config(SIM_TOML))     # no marker: tests/conftest.py switched tolerances off
    assert b.truth().zero_offset_m == 0.0 and b.truth().pointing.nominal
    assert b.truth().mzi_delay_s == b.cfg.monitor.delay_s
    assert load_config(SIM_TOML, environ=NOMINAL_ENV).sim.tolerances.enabled is False
