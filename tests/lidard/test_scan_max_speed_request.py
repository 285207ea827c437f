"""The maximum speed is a scan request (scan.max_speed_mps the default): the CLI flag, the API body,
the job store's round trip and the plan that the digitizer is sized by."""

import pytest

from lidard.api.schemas import ScanCreate, check_scan_body
from lidard.cli.base import CliError
from lidard.cli.lidarctl import build_parser
from lidard.cli.scan import request_body
from lidard.config import load_config
from lidard.instrument.scan_loop import plan_scan
from lidard.jobs import request_from_dict
from lidard.jobs.kinds import request_to_dict
from tests.helpers.tolerances import NOMINAL_ENV


def _cfg():
    return load_config("config/sim.toml", environ=NOMINAL_ENV)


def test_the_body_takes_the_configs_default_when_left_out_and_the_request_otherwise():
    cfg = _cfg()
    assert ScanCreate().to_request(cfg.scan).max_speed_mps == cfg.scan.max_speed_mps == 0.4
    assert ScanCreate(max_speed_mps=7.5).to_request(cfg.scan).max_speed_mps == 7.5


@pytest.mark.parametrize("bad", [0, -1.0, 101.0, float("nan"), "3", True])
def test_a_bad_speed_is_refused_naming_the_field(bad):
    with pytest.raises(ValueError, match="max_speed_mps"):
        check_scan_body({"max_speed_mps": bad})


def test_the_cli_flag_goes_into_the_body_and_a_bad_one_is_refused_before_any_bench():
    ap = build_parser()
    args = ap.parse_args(["scan", "--sim", "--max-speed", "2.5"])
    assert request_body(args, "ply")["max_speed_mps"] == 2.5
    assert "max_speed_mps" not in request_body(ap.parse_args(["scan", "--sim"]), "ply")
    with pytest.raises(CliError, match="max_speed_mps"):
        request_body(ap.parse_args(["scan", "--sim", "--max-speed", "-1"]), "ply")


def test_the_stored_request_keeps_the_speed():
    req = check_scan_body({"max_speed_mps": 3.0}).to_request(_cfg().scan)
    assert request_from_dict(request_to_dict(req)).max_speed_mps == 3.0
    assert request_from_dict({"pattern": "raster"}).max_speed_mps is None     # an older record: the default


def test_the_plans_rate_and_record_grow_with_the_requested_band_only():
    cfg = _cfg()
    optics = cfg.optics()
    slow, fast = (plan_scan(cfg, optics, check_scan_body({"max_speed_mps": v, "rows": [0, 2], "cols": [0, 2]})
                            .to_request(cfg.scan)) for v in (0.4, 10.0))
    assert (slow.dsp.max_speed_mps, fast.dsp.max_speed_mps) == (0.4, 10.0)
    # 2.5x Nyquist of f_R(2 m) + f_D: 5 MHz x 1,190 samples at 0.4 m/s; 40 MHz x 9,520 at 10 m/s
    assert (slow.adc.fs_hz, slow.adc.record_length) == (5e6, 1190)
    assert (fast.adc.fs_hz, fast.adc.record_length) == (40e6, 9520)
