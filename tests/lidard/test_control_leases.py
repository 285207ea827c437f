"""The control lease cannot lock its owner out: ``lidarctl control acquire`` stores the lease where
the same user's later calls find it (or prints an eval line), every 423 says what to send, and a
holder hands the lock over under a fresh lease (the old one void) without a window for anyone else."""

import json
import os
import re
import stat
import subprocess
import sys

import pytest

from tests.helpers.deadlines import WAIT_S
from lidard.api.control import LEASE_HEADER
from tests.helpers.api import live_server, make_app
from tests.helpers.cli import run as lidarctl
from tests.helpers.fakes import FakeInstrument

SMALL = {"pattern": "roi", "rows": [0, 1], "cols": [0, 4]}
SCAN = ("scan", "--rows", "0:1", "--cols", "0:2", "--json")


@pytest.fixture
def live(tmp_path, monkeypatch):
    monkeypatch.delenv("LIDARD_LEASE", raising=False)
    inst = FakeInstrument(profile="fpsa20")
    with live_server(make_app(tmp_path / "data", inst, progress_interval_s=0.0)) as url:
        yield url, inst


def test_acquire_stores_the_lease_for_the_same_users_later_calls(live, capsys, monkeypatch, tmp_path):
    from lidard.cli import leases
    url, inst = live
    code, out, err = lidarctl(capsys, "control", "acquire", "--url", url, "--client", "rig-pc")
    assert code == 0, err
    path = leases.path()
    assert str(path) in out and path.is_relative_to(os.environ["XDG_STATE_HOME"])
    stored = json.loads(path.read_text())
    assert list(stored) == [url] and re.fullmatch(r"[0-9a-f]{48}", stored[url])
    assert stat.S_IMODE(path.stat().st_mode) == 0o600          # a lease steers the laser: owner only
    # the README's next command, with nothing exported: it carries the stored lease
    code, out, err = lidarctl(capsys, *SCAN, "--url", url)
    assert code == 0, err
    assert json.loads(out)["state"] == "done" and len(inst.requests) == 1
    # another user of the same daemon (their own state directory) is refused, and told what to send
    mine = os.environ["XDG_STATE_HOME"]
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "other-user"))
    code, out, err = lidarctl(capsys, *SCAN, "--url", url)
    assert code == 1 and len(inst.requests) == 1 and len(err.strip().splitlines()) == 1
    assert "423" in err and "rig-pc" in err and LEASE_HEADER in err
    assert "--lease" in err and "$LIDARD_LEASE" in err and str(leases.path()) in err
    assert "control acquire" in err and "hand it over" in err
    # the holder releases: the stored lease is forgotten, the lock is free
    monkeypatch.setenv("XDG_STATE_HOME", mine)
    code, out, err = lidarctl(capsys, "control", "release", "--url", url)
    assert code == 0 and "free" in out, err
    assert json.loads(path.read_text()) == {}
    code, out, err = lidarctl(capsys, "control", "status", "--url", url, "--json")
    assert json.loads(out)["held"] is False


def test_acquire_export_prints_one_eval_line_and_stores_nothing(live, tmp_path):
    from lidard.cli import leases
    url, inst = live
    env = {**os.environ, "PYTHONPATH": os.getcwd()}
    lidarctl_cmd = f"{sys.executable} -c 'import sys; from lidard.cli import lidarctl_main; sys.exit(lidarctl_main())'"
    # eval in a real shell, then a mutating command that finds the lease in the environment only
    script = (f'eval "$({lidarctl_cmd} control acquire --export --url {url} --client shell)" && '
              f'echo "lease=$LIDARD_LEASE" && {lidarctl_cmd} {" ".join(SCAN)} --url {url} >/dev/null; '
              f'echo "scan=$?"')
    proc = subprocess.run(["bash", "-c", script], capture_output=True, text=True, env=env, timeout=WAIT_S)
    assert re.search(r"^lease=[0-9a-f]{48}$", proc.stdout, re.M), proc.stdout + proc.stderr
    assert "scan=0" in proc.stdout and len(inst.requests) == 1, proc.stdout + proc.stderr
    assert not leases.path().exists()
    # without it, the same command is refused: the lease really was what let it through
    proc = subprocess.run([sys.executable, "-c", "import sys; from lidard.cli import lidarctl_main; "
                           "sys.exit(lidarctl_main())", *SCAN, "--url", url], capture_output=True,
                          text=True, env={k: v for k, v in env.items() if k != "LIDARD_LEASE"}, timeout=WAIT_S)
    assert proc.returncode == 1 and "423" in proc.stderr and "shell" in proc.stderr and len(inst.requests) == 1


def test_a_holder_hands_over_under_a_fresh_lease_and_the_old_one_is_void(make_client):
    c = make_client(FakeInstrument(), progress_interval_s=0.0)
    assert c.post("/control/handover", json={"client": "viewer"}).status_code == 409   # nothing to hand over
    old = c.post("/control", json={"client": "cli"}).json()["lease"]
    r = c.post("/control/handover", json={"client": "viewer"})              # without the lease
    assert r.status_code == 423 and LEASE_HEADER in r.json()["detail"] and r.json()["holder"] == "cli"
    r = c.post("/control/handover", json={"client": "viewer"}, headers={LEASE_HEADER: old})
    assert r.status_code == 201, r.text
    new = r.json()
    assert new["holder"] == "viewer" and new["lease"] != old
    assert c.get("/control").json()["holder"] == "viewer"
    # the old lease is void: neither a scan nor a release (an old page's late release) goes through
    assert c.post("/scans", json=SMALL, headers={LEASE_HEADER: old}).status_code == 423
    assert c.delete("/control", headers={LEASE_HEADER: old}).status_code == 423
    assert c.post("/scans", json=SMALL, headers={LEASE_HEADER: new["lease"]}).status_code == 201


def test_lidarctl_handover_prints_the_new_lease_and_forgets_its_own(live, capsys):
    from lidard.cli import leases
    url, inst = live
    assert lidarctl(capsys, "control", "acquire", "--url", url, "--client", "me")[0] == 0
    code, out, err = lidarctl(capsys, "control", "handover", "--url", url)
    assert code == 1 and "--client" in err
    code, out, err = lidarctl(capsys, "control", "handover", "--url", url, "--client", "colleague")
    assert code == 0, err
    lease = re.search(r"export LIDARD_LEASE=([0-9a-f]{48})", out).group(1)
    assert leases.load(url) is None
    code, out, err = lidarctl(capsys, *SCAN, "--url", url)          # mine is gone: refused
    assert code == 1 and "colleague" in err
    code, out, err = lidarctl(capsys, *SCAN, "--url", url, "--lease", lease)
    assert code == 0, err
