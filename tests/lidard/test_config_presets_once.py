"""A configuration resolves its presets once: the profile, the laser preset and the optics are one
immutable object (Config.resolved) that every view shares, with no file access after the first; the
preset files are read once per file version across configurations; a configuration resolved after a
file changed sees the new version, one resolved before keeps its own."""

from __future__ import annotations

import dataclasses
import os
import shutil
from pathlib import Path

import pytest

import lidard.config as config
from lidard.config import CONFIG_DIR, Config, ConfigError, ResolvedConfig


def _setup(tmp_path: Path) -> Config:
    shutil.copytree(CONFIG_DIR / "profiles", tmp_path / "profiles")
    return Config(base_dir=str(tmp_path))


def test_every_view_reads_each_preset_file_once(tmp_path, monkeypatch):
    cfg = _setup(tmp_path)
    reads: list[str] = []
    real = config._read_toml
    monkeypatch.setattr(config, "_read_toml", lambda p: reads.append(Path(p).name) or real(p))
    for _ in range(3):
        profile = cfg.load_profile()
        optics = cfg.optics()
        cfg.load_laser()
        cfg.link_params()
    assert sorted(reads) == ["fpsa128.toml", "lasers.toml"]
    assert cfg.load_profile() is profile and cfg.optics() is optics
    assert (optics.rows, optics.cols) == (profile.rows, profile.cols) == (128, 128)


def test_resolved_once_then_no_file_is_touched(tmp_path, monkeypatch):
    cfg = _setup(tmp_path)
    r = cfg.resolved
    assert isinstance(r, ResolvedConfig)
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.laser = r.laser                                            # type: ignore[misc]

    def no_io(*a, **k):
        raise AssertionError("a resolved configuration read a file")
    monkeypatch.setattr(config, "_read_toml", no_io)
    monkeypatch.setattr(config, "_stamp", no_io)
    assert cfg.resolved is r
    assert (cfg.load_profile(), cfg.load_laser(), cfg.optics()) == (r.profile, r.laser, r.optics)
    assert r.optics.focal_m == r.profile.lenses[r.profile.default_lens].focal_m
    assert r.optics.wavelength_m == cfg.chirp.wavelength_m


def test_a_copy_with_other_presets_resolves_its_own(tmp_path):
    cfg = _setup(tmp_path)
    r = cfg.resolved
    other = next(n for n in config.load_lasers(tmp_path / "profiles") if n != cfg.laser)
    copy = cfg.model_copy(update={"laser": other})
    assert copy.resolved.laser == config.load_laser(other, tmp_path / "profiles") != r.laser
    assert copy.resolved.profile is r.profile
    assert cfg.resolved is r                          # the original keeps its own
    lens = next(n for n in r.profile.lenses if n != r.profile.default_lens)
    assert cfg.model_copy(update={"lens": lens}).resolved.optics.focal_m == r.profile.lenses[lens].focal_m


def test_a_changed_file_is_seen_by_a_configuration_resolved_after(tmp_path):
    cfg = _setup(tmp_path)
    assert cfg.resolved.profile.rows == 128
    path = tmp_path / "profiles" / "fpsa128.toml"
    text = path.read_text().replace("rows = 128", "rows = 64", 1)
    path.write_text(text)
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))   # a new version, whatever the clock
    fresh = Config(base_dir=str(tmp_path))
    assert fresh.resolved.profile.rows == 64 and fresh.optics().rows == 64
    assert cfg.resolved.profile.rows == 128 and cfg.optics().rows == 128   # resolved before: unchanged


def test_resolving_names_the_key_that_does_not_fit_the_presets(tmp_path):
    cfg = _setup(tmp_path)
    limit = cfg.resolved.laser.max_current_ma
    over = cfg.model_copy(update={"devices": cfg.devices.model_copy(update={
        "controller": cfg.devices.controller.model_copy(update={"laser_current_ma": limit + 1.0})})})
    with pytest.raises(ConfigError, match=r"devices\.controller\.laser_current_ma: .* above the maximum current"):
        _ = over.resolved
    with pytest.raises(ConfigError, match=r"lens: 'fisheye' is not a lens of profile fpsa128; allowed: "):
        _ = Config(base_dir=str(tmp_path), lens="fisheye").resolved
    with pytest.raises(ConfigError, match=r"laser: 'nope' is not a preset; allowed: .*dfb_default"):
        _ = Config(base_dir=str(tmp_path), laser="nope").resolved


def test_a_copy_of_the_lasers_is_handed_out(tmp_path):
    cfg = _setup(tmp_path)
    presets = config.load_lasers(tmp_path / "profiles")
    n = len(presets)
    presets.clear()                                   # the caller's dict, not the cache's
    assert len(config.load_lasers(tmp_path / "profiles")) == n > 0
    assert cfg.load_laser() is config.load_lasers(tmp_path / "profiles")[cfg.laser]
