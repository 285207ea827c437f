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
