"""Configuration loading: defaults, env overrides, one clear error per bad file, no partial load."""

import pytest

from lidard.config import ConfigError, load_config, load_laser, load_lasers, load_profile


def test_shipped_configs_load_with_their_presets():
    sim = load_config("config/sim.toml")
    lab = load_config("config/lab.toml")
    assert sim.sim.enabled and not lab.sim.enabled
    assert sim.chirp.excursion_hz == 8.6e9 and sim.chirp.ramp_s == 80e-6
    assert sim.chirp.rate_hz_per_s == pytest.approx(1.075e14)
    assert lab.devices.controller.host != "bench"


def test_every_laser_preset_validates_and_default_linewidth_follows_table_2_2():
    presets = load_lasers()
    assert {"dfb_default", "dfb_strong_nonlinear", "dfb_slow_thermal", "dfb_broad_linewidth"} <= set(presets)
    dfb = load_laser("dfb_default")
    assert dfb.linewidth_hz == pytest.approx(1 / (3.141592653589793 * 0.64e-6))
    # thermal tuning has the opposite sign of the carrier term and dominates
    assert dfb.carrier_hz_per_v > 0 > dfb.static_tuning_hz_per_v
    assert presets["ideal"].linewidth_hz == 0.0


def test_env_override_wins(tmp_path):
    cfg = load_config("config/sim.toml", environ={"LIDARD__ADC__BITS": "12", "LIDARD__SIM__SEED": "7"})
    assert cfg.adc.bits == 12 and cfg.sim.seed == 7
    assert "LIDARD__ADC__BITS" in cfg.source


def _write(tmp_path, text):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("body, key, allowed", [
    ("[adc]\nbits = 9\n", "adc.bits", "8, 10, 12, 14 or 16"),
    ("[adc]\nbitz = 8\n", "adc.bitz", "unknown key"),
    ("[chirp]\nramp_s = -1.0\n", "chirp.ramp_s", "greater than 0"),
    ("[link]\nreference = 'laser'\n", "link.reference", "'backreflection' or 'mzi'"),
    ("[daemon]\nport = 70000\n", "daemon.port", "less than or equal to 65535"),
])
def test_bad_values_name_file_key_and_rule(tmp_path, body, key, allowed):
    path = _write(tmp_path, body)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    msg = str(info.value)
    assert str(path) in msg and key in msg and allowed in msg
    assert "\n" not in msg  # one line


def test_unknown_profile_and_laser_list_what_is_allowed(tmp_path):
    with pytest.raises(ConfigError, match="fpsa128"):
        load_config(_write(tmp_path, "profile = 'fpsa999'\n"))
    with pytest.raises(ConfigError, match="dfb_default"):
        load_config(_write(tmp_path, "laser = 'nope'\n"))
    with pytest.raises(ConfigError, match="lidar_25mm"):
        load_config(_write(tmp_path, "lens = 'fisheye'\n"))


def test_invalid_toml_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(_write(tmp_path, "[adc\nbits=8"))
    with pytest.raises(ConfigError, match="file not found"):
        load_config(tmp_path / "missing.toml")


def test_profile_rules_are_checked(tmp_path):
    prof = tmp_path / "profiles"
    prof.mkdir()
    text = open("config/profiles/fpsa20.toml").read().replace("release_v = 29.0", "release_v = 33.0")
    (prof / "weird.toml").write_text(text)
    with pytest.raises(ConfigError, match="release_v < pull_in_v"):
        load_profile("weird", prof)
