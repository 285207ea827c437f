"""``[chirp] linear_window``: where the linearization makes the chirp linear. "core" (default) is the
ILC's centre region as before the key existed (ROI 0.8, learning 0.92; the calibration caches and
set-up hashes unchanged); "range" is the range FFT's window (``FrameDsp.use_fraction``) plus a
learning margin, for far-range work (docs/measured/26_range_linearity.md). No linearization is run:
the ILC is replaced by a stub that records the settings it was given."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from lidard.config import CONFIG_DIR, load_config
from lidard.dsp.frame import FrameDsp
from lidard.instrument.acquisition import AWG_RATE_HZ
from lidard.instrument.calibration import linearization as lin_mod
from lidard.instrument.calibration.setup import calibration_setup
from lidard.store.calcache import config_key

SIM = CONFIG_DIR / "sim.toml"
SIM_FAR = CONFIG_DIR / "sim_far.toml"


class _Stop(Exception):
    pass


class _Safety:
    def bring_up(self):
        pass

    def bring_down(self):
        pass


def _learned_region(cfg, monkeypatch) -> tuple[float, float]:
    """(ROI, learning region) the linearization hands the ILC for ``cfg``."""
    seen = {}

    def fake_ilc(measure, drive_v, geometry, settings):
        seen["roi"], seen["learn"] = settings.roi, settings.learn
        raise _Stop

    monkeypatch.setattr(lin_mod, "ilc_linearize", fake_ilc)
    lin = lin_mod.Linearization(cfg, cfg.resolved.optics, lifecycle=None, safety=_Safety())  # type: ignore[arg-type]
    with pytest.raises(_Stop):
        lin.run(np.zeros(int(round(2 * cfg.chirp.ramp_s * AWG_RATE_HZ))), cfg.laser)
    return seen["roi"], seen["learn"]


def test_default_is_the_core_region_of_main(monkeypatch):
    cfg = load_config(SIM)
    assert cfg.chirp.linear_window == "core"
    assert _learned_region(cfg, monkeypatch) == (0.8, 0.92)


def test_range_window_learns_the_range_ffts_window(monkeypatch):
    cfg = load_config(SIM_FAR)       # far-range config: sets linear_window = "range"
    assert cfg.chirp.linear_window == "range"
    roi, learn = _learned_region(cfg, monkeypatch)
    use_fraction = FrameDsp.__dataclass_fields__["use_fraction"].default
    assert roi == use_fraction == 0.9       # the region the range estimator uses: one value
    assert roi < learn <= 1.0 and learn == pytest.approx(0.95)
    # the same key on the lab config does the same
    lab = load_config(SIM, environ={"LIDARD__CHIRP__LINEAR_WINDOW": "range"})
    assert _learned_region(lab, monkeypatch) == (roi, learn)


def test_default_keeps_the_calibration_keys_and_range_changes_them():
    cfg = load_config(SIM, environ={})
    # not in any dump (calibration cache key, set-up hash, sweep hash): the keys are those of before
    assert "linear_window" not in cfg.model_dump(mode="json")["chirp"]
    assert "linear_window" not in cfg.model_dump()["chirp"]
    wide = load_config(SIM, environ={"LIDARD__CHIRP__LINEAR_WINDOW": "range"})
    assert wide.model_dump(mode="json")["chirp"]["linear_window"] == "range"
    assert config_key(wide) != config_key(cfg)
    assert calibration_setup(wide)["range"].hash != calibration_setup(cfg)["range"].hash
    # the default spelled out is the default: same keys as not setting it
    explicit = load_config(SIM, environ={"LIDARD__CHIRP__LINEAR_WINDOW": "core"})
    assert config_key(explicit) == config_key(cfg)


def test_unknown_window_is_refused_naming_the_key():
    with pytest.raises(ValidationError, match="linear_window"):
        type(load_config(SIM).chirp).model_validate({"linear_window": "edges"})
    with pytest.raises(ValueError, match="chirp.linear_window"):
        lin_mod.ilc_region("edges")


# ------------------------------------------------------------------ the health check's region

TAIL_HZ = 5e6               # peak of the turnaround's tail a core drive leaves inside the range window
TAIL_AT, TAIL_HALF = 0.072, 0.017    # its centre and half width, fractions of a ramp from its start


def _tail(s: np.ndarray) -> np.ndarray:
    """A raised-cosine frequency error (Hz) at ramp fractions ``s`` in [0.055, 0.089]: inside the range
    window (0.05-0.95 of a ramp), outside the core region (0.1-0.9)."""
    u = np.clip((s - TAIL_AT) / TAIL_HALF, -1.0, 1.0)
    return TAIL_HZ * 0.5 * (1 + np.cos(np.pi * u))


def _monitor_records(geom, n: int, quadrature: bool) -> np.ndarray:
    """Monitor-MZI records, one drive period each, of a triangle chirp (the ideal slope) with ``_tail``
    after each turnaround: the fringe exp(j (phi(t) - phi(t - tau))), or its real part."""
    m = int(round(2 * geom.ramp_s * geom.fs_adc_hz))
    t = np.arange(2 * m) / geom.fs_adc_hz             # two periods: the delayed copy needs the first
    tp = np.mod(t, 2 * geom.ramp_s)
    up = tp < geom.ramp_s
    slope = geom.excursion_hz / geom.ramp_s
    nu = np.where(up, slope * (tp - geom.ramp_s / 2), -slope * (tp - 1.5 * geom.ramp_s))
    nu = nu + _tail(np.where(up, tp, tp - geom.ramp_s) / geom.ramp_s)
    phi = 2 * np.pi * np.cumsum(nu) / geom.fs_adc_hz
    k = int(round(geom.mzi_delay_s * geom.fs_adc_hz))
    dphi = phi[m:] - phi[m - k:2 * m - k]
    fringe = np.exp(1j * dphi) if quadrature else np.cos(dphi)
    return np.repeat(fringe[None, :], n, axis=0)


def _tail_rms_over(roi: float) -> float:
    """Ground truth: the tail's RMS over the central ``roi`` of a ramp, its mean (the free offset) removed."""
    s = np.linspace(0.5 * (1 - roi), 0.5 * (1 + roi), 200_001)
    e = _tail(s)
    return float(np.sqrt(np.mean((e - e.mean()) ** 2)))


@pytest.mark.parametrize("path, window", [(SIM, None), (SIM, "range"), (SIM_FAR, None)])
def test_the_health_check_measures_the_region_the_chirp_was_linearized_over(monkeypatch, path, window):
    from lidard.instrument.calibration.health import LinearizationHealth
    cfg = load_config(path, environ={} if window is None else {"LIDARD__CHIRP__LINEAR_WINDOW": window})
    roi, _ = _learned_region(cfg, monkeypatch)          # the region the ILC was handed
    health = LinearizationHealth(cfg, cfg.resolved.optics, lifecycle=None, safety=_Safety())  # type: ignore[arg-type]
    geom = health._lin.geometry()
    health._lin.measure = lambda drive_v, n_avg, record_length=None: _monitor_records(  # type: ignore[method-assign]
        geom, n_avg, bool(cfg.monitor.quadrature))
    n = int(round(2 * cfg.chirp.ramp_s * AWG_RATE_HZ))
    drive = np.concatenate([np.linspace(-1, 1, n // 2, endpoint=False), np.linspace(1, -1, n // 2, endpoint=False)])
    r = health.check(drive)
    if cfg.chirp.linear_window == "range":
        # the tail is inside the region linearized over: it counts, and re-linearizes
        assert roi == 0.9
        expected = _tail_rms_over(roi)
        assert r.up_error_hz == pytest.approx(expected, rel=0.1)
        assert r.down_error_hz == pytest.approx(expected, rel=0.1)
        assert r.exceeded and expected > 2 * r.threshold_hz
    else:
        # outside the core region the drive was never made linear: not evidence of a stale drive
        assert roi == 0.8 and _tail_rms_over(roi) == 0.0
        assert r.residual_hz < 0.05 * _tail_rms_over(0.9) and not r.exceeded
