"""``lidarctl sweep`` as a command: a missing offline extra names the install command, a bad sweep
file exits 2 naming the key, --dry-run counts, a real (tiny) run prints the summary; and the task's
rule for phase-noise compensation is the daemon's."""

from __future__ import annotations

import importlib.util
from types import SimpleNamespace

import pytest

from lidard.config import load_config
from lidard.offline import sweep_cli
from lidard.offline.sweep import phase_noise_on

SWEEP = """
[sweep]
name = "cli"
base_config = "sim.toml"
seeds = 1
trials_per_task = 2
[grid]
"scan.max_range_m" = 15.0
{grid}
[target]
distances_m = [3.0, 6.0]
"""


def _write(tmp_path, grid: str = "") -> str:
    p = tmp_path / "s.toml"
    p.write_text(SWEEP.format(grid=grid))
    return str(p)


def test_without_the_offline_extra_the_command_names_the_install(monkeypatch, tmp_path, capsys):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "pyarrow" else real(name, *a))
    assert sweep_cli.sweep_main([_write(tmp_path)]) == sweep_cli.EXIT_ERROR
    err = capsys.readouterr().err
    assert "missing: pyarrow" in err and 'pip install -e ".[offline]"' in err


def test_a_bad_sweep_file_exits_2_naming_the_key(tmp_path, capsys):
    assert sweep_cli.sweep_main([_write(tmp_path, '"link.tx_pwr_w" = 1e-3')]) == sweep_cli.EXIT_ERROR
    assert "grid.link.tx_pwr_w: unknown key" in capsys.readouterr().err


def test_dry_run_counts_and_a_run_prints_the_summary(tmp_path, capsys):
    spec = _write(tmp_path, '"link.tx_power_w" = [1e-3, 1e-2]')
    assert sweep_cli.sweep_main([spec, "--dry-run", "--out", str(tmp_path / "o")]) == 0
    assert "2 configurations, 4 tasks" in capsys.readouterr().out
    assert not (tmp_path / "o").exists()
    assert sweep_cli.sweep_main([spec, "--in-process", "--no-plot", "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "ran 4 tasks (0 already done)" in out and "link.tx_power_w" in out
    assert (tmp_path / "o" / "summary.csv").is_file() and not (tmp_path / "o" / "sweep.png").exists()
    assert sweep_cli.sweep_main([spec, "--in-process", "--no-plot", "--out", str(tmp_path / "o")]) == 0
    assert "ran 0 tasks (4 already done)" in capsys.readouterr().out


@pytest.mark.parametrize("flag", ["--workers", "--batch"])
def test_workers_and_batch_must_be_positive(tmp_path, capsys, flag):
    assert sweep_cli.sweep_main([_write(tmp_path), flag, "0"]) == sweep_cli.EXIT_ERROR
    assert f"{flag} must be >= 1" in capsys.readouterr().err


@pytest.mark.parametrize("max_range_m", [2.0, 15.0, 40.0, 59.0, 60.0, 150.0])
@pytest.mark.parametrize("mode", ["auto", "on", "off"])
def test_the_task_turns_phase_noise_compensation_on_like_the_daemon(max_range_m, mode):
    from lidard.instrument.scan_loop import phase_noise_on as daemon_rule
    cfg = load_config(environ={"LIDARD__SCAN__PHASE_NOISE_COMPENSATION": mode})
    request = SimpleNamespace(max_range_m=max_range_m, phase_noise_compensation=None)
    assert phase_noise_on(cfg, max_range_m) == daemon_rule(cfg, request)


def test_scheduler_flag_runs_the_sweep_on_an_existing_scheduler(client, tmp_path, capsys):
    address = client.scheduler.address          # the in-process cluster's scheduler, as a remote one would be
    spec = _write(tmp_path)
    assert sweep_cli.sweep_main([spec, "--scheduler", address, "--no-plot", "--out", str(tmp_path / "o")]) == 0
    assert "ran 2 tasks (0 already done)" in capsys.readouterr().out
    assert client.scheduler_info()["workers"]    # the scheduler (not ours to close) is still up


def test_lidarctl_registers_the_sweep_command(tmp_path, capsys):
    from lidard.cli.lidarctl import main
    assert main(["sweep", _write(tmp_path, '"link.tx_power_w" = [1e-3, 1e-2]'), "--dry-run"]) == 0
    assert "2 configurations, 4 tasks" in capsys.readouterr().out
    assert main(["sweep", _write(tmp_path, '"laser" = "nope"')]) == sweep_cli.EXIT_ERROR
    assert "laser: 'nope' is not a preset" in capsys.readouterr().err
