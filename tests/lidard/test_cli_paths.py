"""Errors that name the real cause: a missing scene file, an --out into a directory that does not exist
(refused before any work, nothing created)."""

import pytest

from lidard.errors import ConfigError
from lidard.outputs import scene_identity
from tests.helpers.cli import run


def test_missing_scene_file_is_named_as_a_scene_not_a_sidecar(capsys, tmp_path):
    missing = tmp_path / "nope.toml"
    code, out, err = run(capsys, "scan", "--sim", "--scene", str(missing), "--pixels", "0,0",
                         "--data-dir", str(tmp_path / "d"), "--no-cal-cache")
    assert code != 0 and out == ""
    assert f"scene file {missing} not found" in err and "sidecar" not in err
    assert len(err.strip().splitlines()) == 1


def test_scene_identity_raises_a_config_error_naming_the_file(tmp_path):
    with pytest.raises(ConfigError, match=r"scene file .*gone\.toml not found"):
        scene_identity(tmp_path / "gone.toml")
    (tmp_path / "s.toml").write_text("x = 1\n")
    assert len(scene_identity(tmp_path / "s.toml")["sha256"]) == 64


@pytest.mark.parametrize("argv", [
    ["scan", "--sim", "--pixels", "0,0", "--out"],
    ["scans", "fetch", "SOMEID", "--out"],
    ["reprocess", "SOMEID", "--out"],
])
def test_out_into_a_missing_directory_is_refused_and_nothing_is_created(capsys, tmp_path, argv):
    target = tmp_path / "no" / "such" / "dir" / "x.ply"
    code, out, err = run(capsys, *argv, str(target))
    assert code != 0
    assert f"directory {tmp_path / 'no' / 'such' / 'dir'} does not exist" in err
    assert not (tmp_path / "no").exists()


def test_out_under_a_file_is_refused(capsys, tmp_path):
    (tmp_path / "afile").write_text("")
    code, _, err = run(capsys, "scan", "--sim", "--pixels", "0,0", "--out", str(tmp_path / "afile" / "x.ply"))
    assert code != 0 and "is not a directory" in err
