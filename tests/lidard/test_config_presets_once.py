"""The presets (profile, lasers) are read and validated once per file version: every view of a
configuration (load_profile, optics, load_laser, link_params) shares them; a changed file is read again."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import lidard.config as config
from lidard.config import CONFIG_DIR, Config


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


def test_a_changed_file_is_read_again(tmp_path):
    cfg = _setup(tmp_path)
    assert cfg.load_profile().rows == 128
    path = tmp_path / "profiles" / "fpsa128.toml"
    text = path.read_text().replace("rows = 128", "rows = 64", 1)
    path.write_text(text)
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))   # a new version, whatever the clock
    assert cfg.load_profile().rows == 64
    assert cfg.optics().rows == 64


def test_a_copy_of_the_lasers_is_handed_out(tmp_path):
    cfg = _setup(tmp_path)
    presets = config.load_lasers(tmp_path / "profiles")
    n = len(presets)
    presets.clear()                                   # the caller's dict, not the cache's
    assert len(config.load_lasers(tmp_path / "profiles")) == n > 0
    assert cfg.load_laser() is config.load_lasers(tmp_path / "profiles")[cfg.laser]
