"""[monitor] quadrature: the hardware switch for phase-noise compensation at any range (issue 15)."""

import pytest

from lidard.config import ConfigError, load_config


def test_quadrature_monitor_defaults_to_the_dissertations_single_mzi_and_parses(tmp_path):
    assert load_config("config/sim.toml").monitor.quadrature is False
    p = tmp_path / "q.toml"
    p.write_text("[monitor]\nquadrature = true\n")
    assert load_config(p).monitor.quadrature is True


def test_a_bad_quadrature_value_names_the_key(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[monitor]\nquadrature = 'maybe'\n")
    with pytest.raises(ConfigError, match="monitor.quadrature"):
        load_config(p)
