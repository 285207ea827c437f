"""What a calibration record's set-up consists of (lidard.instrument.calibration.setup): each part that
changes the range or pointing truth changes that kind's hash and is named; what does not, does not."""

from __future__ import annotations

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument.calibration.setup import calibration_setup, select
from lidard.store import CalibrationRecord

SIM = CONFIG_DIR / "sim.toml"


def _setup(**env):
    return calibration_setup(load_config(SIM, environ={f"LIDARD__{k.upper()}": v for k, v in env.items()}))


def test_each_part_moves_only_its_kinds_hash():
    base = _setup()
    laser = _setup(laser="ideal")
    assert laser["range"].hash != base["range"].hash and laser["pointing"].hash == base["pointing"].hash
    assert base["range"].differs(laser["range"].as_dict()) == (
        "it was made on another set-up (laser ideal here dfb_default, receiver differ)")
    lens = _setup(profile="fpsa20", lens="singlet_4p51mm")
    assert lens["pointing"].hash != base["pointing"].hash and "profile fpsa20 here fpsa128" in \
        base["pointing"].differs(lens["pointing"].as_dict())
    delay = _setup(monitor__delay_s="201e-9")
    assert delay["range"].hash != base["range"].hash and delay["pointing"].hash == base["pointing"].hash
    bench = _setup(sim__seed="2")                 # another simulated bench: both kinds, named "instruments"
    assert bench["range"].hash != base["range"].hash and bench["pointing"].hash != base["pointing"].hash
    assert "instruments" in base["pointing"].differs(bench["pointing"].as_dict())
    # what a scan sets, not the instrument: the max speed (ADC rate), the scan defaults, the scene
    # ... and how the DSP judges points: the harmonic screen's level (a stored calibration stays valid)
    same = _setup(scan__max_speed_mps="3.0", scan__averages="4", sim__scene="scenes/empty.toml", adc__sfdr_dbc="25")
    assert same["range"].hash == base["range"].hash and same["pointing"].hash == base["pointing"].hash


def test_real_hardware_is_tied_to_the_devices_identities():
    cfg = load_config(CONFIG_DIR / "lab.toml")
    a = calibration_setup(cfg, {"awg": "serial=A1", "digitizer": "SN 7"})
    b = calibration_setup(cfg, {"awg": "serial=A2", "digitizer": "SN 7"})
    assert a["range"].hash != b["range"].hash and "instruments" in a["range"].differs(b["range"].as_dict())
    assert a.hash != b.hash


def test_select_takes_the_newest_record_of_this_set_up():
    base, other = _setup()["range"], _setup(laser="ideal")["range"]

    def rec(i, setup):
        return CalibrationRecord(f"r{i}", "range", float(i), None, {"setup": setup.as_dict()} if setup else {}, {}, {})
    newest_first = [rec(4, other), rec(3, None), rec(2, base), rec(1, base)]
    assert select(newest_first, base)[0].id == "r2"
    got, why = select(newest_first[:2], base)
    assert got is None and why.startswith("range calibration r4 not used: it was made on another set-up")
    assert select([], base) == (None, None)
    assert select(newest_first, None)[0].id == "r4"       # no set-up known: the newest, as before
