"""The calibration cache of one-shot ``--sim`` commands (lidard.store.calcache, issue 18).

A second embedded scan of the same configuration reuses the first one's linearization (same id,
no second linearize call); another laser preset, a moved laser temperature or ``--no-cal-cache``
linearize again. The bench is a FakeInstrument that counts linearize calls.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import pytest

from lidard.store import calcache
from lidard.cli import base as cli_base
from lidard.cli.embedded import embedded, sim_config
from lidard.config import CONFIG_DIR
from lidard.jobs import request_from_dict
from tests.helpers.fakes import FakeInstrument


def _args(**kw):
    return SimpleNamespace(config=str(CONFIG_DIR / "sim.toml"), profile="fpsa20", data_dir=None,
                           no_cal_cache=None, **kw)


def _scan_calibration_id(args, inst, cfg=None) -> str:
    """One small embedded scan; the id of the calibration it used."""
    with embedded(args, cfg) as (worker, store, _):
        rec = worker.submit_scan(request_from_dict({"pattern": "roi", "rows": [0, 1], "cols": [0, 2]}))
        final = worker.wait(rec.id)
    assert final.state == "done", final.error
    assert inst.calibrations_used[-1] is not None
    return inst.calibrations_used[-1].meta["id"]


@pytest.fixture
def fake(monkeypatch):
    inst = FakeInstrument(profile="fpsa20")
    monkeypatch.setattr(cli_base, "open_instrument", lambda cfg, **kw: inst)
    return inst


def test_cache_dir_follows_xdg(tmp_path):
    assert calcache.cache_dir({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "lidard"
    assert calcache.cache_dir({"HOME": "/nonexistent"}).parts[-2:] == (".cache", "lidard")


def test_second_scan_reuses_the_cached_calibration(fake):
    first = _scan_calibration_id(_args(), fake)
    assert fake.linearize_calls == 1
    assert list((calcache.cache_dir() / "calibrations").glob("*.npz"))
    second = _scan_calibration_id(_args(), fake)
    assert fake.linearize_calls == 1          # not linearized again
    assert second == first


def test_another_laser_preset_is_another_key(fake):
    cfg = sim_config(_args())
    others = [n for n in _laser_names() if n != cfg.laser]
    if not others:
        pytest.skip("only one laser preset is shipped")
    other = cfg.model_copy(update={"laser": others[0]})
    assert calcache.config_key(other) != calcache.config_key(cfg)
    _scan_calibration_id(_args(), fake, cfg)
    _scan_calibration_id(_args(), fake, other)
    assert fake.linearize_calls == 2


def test_changed_preset_values_change_the_key(monkeypatch):
    cfg = sim_config(_args())
    key = calcache.config_key(cfg)
    resolved = cfg.resolved
    preset = resolved.laser
    moved = preset.model_copy(update={"coherence_time_s": preset.coherence_time_s * 2})
    # the same preset name, other values (a new version of lasers.toml)
    monkeypatch.setattr(type(cfg), "resolved", property(lambda self: dataclasses.replace(resolved, laser=moved)))
    assert calcache.config_key(cfg) != key


def test_scan_only_sections_do_not_change_the_key():
    cfg = sim_config(_args())
    scan = cfg.scan.model_copy(update={"averages": cfg.scan.averages + 3})
    assert calcache.config_key(cfg.model_copy(update={"scan": scan})) == calcache.config_key(cfg)


def test_the_doppler_band_is_a_scan_request_not_part_of_the_key(fake):
    # the band sizes the digitizer for one scan; the linearized drive does not depend on it
    cfg = sim_config(_args())
    fast = cfg.model_copy(update={"scan": cfg.scan.model_copy(update={"max_speed_mps": 10.0})})
    assert calcache.config_key(fast) == calcache.config_key(cfg)
    first = _scan_calibration_id(_args(), fake)
    with embedded(_args(), None) as (worker, store, _):      # a 10 m/s request on the same cache
        rec = worker.submit_scan(request_from_dict({"pattern": "roi", "rows": [0, 1], "cols": [0, 2],
                                                    "max_speed_mps": 10.0}))
        assert worker.wait(rec.id).state == "done"
    assert fake.linearize_calls == 1 and fake.calibrations_used[-1].meta["id"] == first


def test_moved_laser_temperature_relinearizes_and_replaces_the_entry(fake):
    first = _scan_calibration_id(_args(), fake)
    cfg = sim_config(_args())
    fake.temperature_c += 10 * cfg.scan.recalibrate_delta_c
    second = _scan_calibration_id(_args(), fake)
    assert fake.linearize_calls == 2 and second != first
    assert calcache.load(cfg).meta["id"] == second


def test_no_cal_cache_neither_reuses_nor_writes(fake, monkeypatch, tmp_path):
    _scan_calibration_id(_args(), fake)                       # fills the cache
    off = _args()
    off.no_cal_cache = True
    _scan_calibration_id(off, fake)
    assert fake.linearize_calls == 2                          # not reused
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "empty"))
    _scan_calibration_id(off, fake)
    assert not (calcache.cache_dir() / "calibrations").exists()   # not written


def test_unreadable_entry_is_ignored(fake):
    cfg = sim_config(_args())
    path = calcache.cache_dir() / "calibrations" / f"{calcache.config_key(cfg)}.npz"
    path.parent.mkdir(parents=True)
    path.write_bytes(b"not an npz")
    _scan_calibration_id(_args(), fake)
    assert fake.linearize_calls == 1
    assert calcache.load(cfg) is not None     # replaced by the new calibration


def _laser_names() -> list[str]:
    from lidard.config import load_lasers
    return list(load_lasers())


def _cli(capsys, *argv):
    from lidard.cli.lidarctl import main
    try:
        code = main(list(argv))
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err


def test_cli_flag_reuses_by_default_and_no_cal_cache_turns_it_off(fake, capsys):
    scan = ("scan", "--sim", "--profile", "fpsa20", "--rows", "0:1", "--cols", "0:2", "--json")
    for _ in range(2):
        assert _cli(capsys, *scan)[0] == 0
    assert fake.linearize_calls == 1
    assert _cli(capsys, *scan, "--no-cal-cache")[0] == 0
    assert fake.linearize_calls == 2
    code, err = _cli(capsys, "scan", "--no-cal-cache")
    assert code != 0 and "--no-cal-cache" in err and "--sim" in err
