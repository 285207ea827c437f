"""Issue 6 control lock: one controlling client, read-only observers, leases on an injected clock."""

import re

import pytest

from lidard.api.control import LEASE_HEADER, ControlLock, LockHeld
from lidard.config import ConfigError, load_config
from tests.helpers.api import app_client, live_server, make_app
from tests.helpers.fakes import FakeInstrument

SMALL = {"pattern": "roi", "rows": [0, 1], "cols": [0, 4]}
TTL = 60.0


class FakeClock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


@pytest.fixture
def env(make_client):
    clock = FakeClock()
    inst = FakeInstrument()
    c = make_client(inst, lease_ttl_s=TTL, clock=clock, progress_interval_s=0.0)
    yield c, inst, c.app, clock


def acquire(c, name, **headers):
    return c.post("/control", json={"client": name}, headers=headers)


def test_no_lease_means_mutations_pass(env):
    c, inst, app, clock = env
    assert c.get("/control").json() == {"held": False, "holder": None, "expires_at": None,
                                        "expires_in_s": None, "ttl_s": TTL}
    assert c.post("/scans", json=SMALL).status_code == 201


def test_holder_steers_others_get_423_naming_holder(env):
    c, inst, app, clock = env
    r = acquire(c, "alice-laptop")
    assert r.status_code == 201
    lease = r.json()["lease"]
    assert r.json()["holder"] == "alice-laptop" and r.json()["ttl_s"] == TTL and len(lease) >= 16
    st = c.get("/control").json()
    assert st["held"] is True and st["holder"] == "alice-laptop" and st["expires_in_s"] == pytest.approx(TTL)
    assert lease not in c.get("/control").text  # observers never see the lease
    # an observer reads freely
    assert c.get("/scans").status_code == 200 and c.get("/health").status_code == 200
    # but cannot mutate: no header, wrong header
    for headers in ({}, {LEASE_HEADER: "not-the-lease"}, {LEASE_HEADER: lease[:-1]}):
        for method, path, kw in [("POST", "/scans", {"json": SMALL}), ("DELETE", "/scans/X", {}),
                                 ("POST", "/calibration/linearize", {}),
                                 ("PUT", "/sim/scene", {"json": {"target": []}})]:
            r = c.request(method, path, headers=headers, **kw)
            assert r.status_code == 423, (method, path, headers)
            assert r.json()["holder"] == "alice-laptop" and "alice-laptop" in r.json()["detail"]
    assert inst.requests == [] and inst.linearize_calls == 0 and inst.scenes == []
    # a second client cannot take the lock
    r = acquire(c, "bob")
    assert r.status_code == 423 and "alice-laptop" in r.json()["detail"]
    # the holder can
    r = c.post("/scans", json=SMALL, headers={LEASE_HEADER: lease})
    assert r.status_code == 201
    assert c.delete(f"/scans/{r.json()['id']}", headers={LEASE_HEADER: lease}).status_code == 200


def test_release_needs_the_lease_then_lock_is_free(env):
    c, inst, app, clock = env
    lease = acquire(c, "alice").json()["lease"]
    r = c.delete("/control")
    assert r.status_code == 423 and c.get("/control").json()["held"] is True
    r = c.delete("/control", headers={LEASE_HEADER: lease})
    assert r.status_code == 200 and r.json()["held"] is False
    assert c.get("/control").json()["held"] is False
    assert c.post("/scans", json=SMALL).status_code == 201
    # the old lease is worthless once released; a new holder gets a new one
    lease2 = acquire(c, "bob").json()["lease"]
    assert lease2 != lease
    assert c.post("/scans", json=SMALL, headers={LEASE_HEADER: lease}).status_code == 423
    # releasing when nobody holds it is a no-op
    c.delete("/control", headers={LEASE_HEADER: lease2})
    assert c.delete("/control").status_code == 200


def test_lease_expires_after_ttl_and_any_use_renews_it(env):
    c, inst, app, clock = env
    lease = acquire(c, "alice").json()["lease"]
    clock.t += TTL - 1
    assert c.get("/health", headers={LEASE_HEADER: lease}).status_code == 200  # a read renews too
    clock.t += TTL - 1
    assert c.get("/control").json()["holder"] == "alice"
    assert c.post("/scans", json=SMALL, headers={LEASE_HEADER: lease}).status_code == 201  # renews
    clock.t += TTL - 1
    assert c.get("/control").json()["expires_in_s"] == pytest.approx(1.0)
    assert c.post("/scans", json=SMALL).status_code == 423
    clock.t += 1.0  # now exactly TTL after the last use: lapsed
    assert c.get("/control").json()["held"] is False
    assert c.post("/scans", json=SMALL).status_code == 201
    assert acquire(c, "bob").status_code == 201


def test_holder_can_renew_and_rename_with_its_lease(env):
    c, inst, app, clock = env
    lease = acquire(c, "alice").json()["lease"]
    clock.t += 30
    r = acquire(c, "alice-2", **{LEASE_HEADER: lease})
    assert r.status_code == 201 and r.json()["lease"] == lease and r.json()["holder"] == "alice-2"
    assert c.get("/control").json()["expires_in_s"] == pytest.approx(TTL)


@pytest.mark.parametrize("body", [{}, {"client": ""}, {"client": "x" * 65}, {"client": "a\nb"},
                                  {"client": "ok", "extra": 1}, {"client": 5}])
def test_bad_acquire_bodies_are_422(env, body):
    c, *_ = env
    assert c.post("/control", json=body).status_code == 422
    assert c.get("/control").json()["held"] is False


def test_lock_unit_expiry_boundary_and_bad_ttl():
    clock = FakeClock()
    lock = ControlLock(ttl_s=10.0, clock=clock)
    lease = lock.acquire("a")
    with pytest.raises(LockHeld, match="'a'"):
        lock.check(None)
    lock.check(lease.token)
    clock.t += 9.999
    assert lock.holder() is not None
    clock.t += 0.001
    assert lock.holder() is None
    lock.check(None)
    for bad in (0, -1, float("nan")):
        with pytest.raises(ValueError, match="ttl_s"):
            ControlLock(ttl_s=bad)


# -- lidarctl control / --lease against a live uvicorn server on a free loopback port
@pytest.fixture
def live(tmp_path):
    inst = FakeInstrument(profile="fpsa20")
    with live_server(make_app(tmp_path / "data", inst, progress_interval_s=0.0)) as url:
        yield url, inst


def lidarctl(capsys, *argv):
    from lidard import cli
    code = cli.lidarctl_main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_lidarctl_control_acquire_status_release_and_lease_header(live, capsys, monkeypatch, tmp_path):
    import json
    url, inst = live
    monkeypatch.delenv("LIDARD_LEASE", raising=False)
    code, out, err = lidarctl(capsys, "control", "status", "--url", url)
    assert code == 0 and "free" in out
    code, out, err = lidarctl(capsys, "control", "acquire", "--url", url, "--client", "rig-pc", "--json")
    assert code == 0, err
    lease = json.loads(out)["lease"]
    code, out, err = lidarctl(capsys, "control", "status", "--url", url)
    assert code == 0 and "rig-pc" in out and lease not in out
    # another user (another lease file, tests/lidard/test_control_leases.py has this user's) has no lease:
    # a command is refused with one line naming the holder
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "other-user"))
    code, out, err = lidarctl(capsys, "scan", "--url", url, "--rows", "0:1", "--cols", "0:2", "--json")
    assert code == 1 and "423" in err and "rig-pc" in err and len(err.strip().splitlines()) == 1
    assert inst.requests == []
    # --lease, then LIDARD_LEASE, make it pass
    code, out, err = lidarctl(capsys, "scan", "--url", url, "--rows", "0:1", "--cols", "0:2", "--json",
                              f"--lease={lease}")
    assert code == 0, err
    assert json.loads(out)["state"] == "done" and len(inst.requests) == 1
    code, out, err = lidarctl(capsys, "control", "release", "--url", url)
    assert code == 1 and "--lease" in err
    monkeypatch.setenv("LIDARD_LEASE", lease)
    code, out, err = lidarctl(capsys, "control", "release", "--url", url)
    assert code == 0 and "free" in out
    monkeypatch.delenv("LIDARD_LEASE")
    code, out, err = lidarctl(capsys, "control", "status", "--url", url, "--json")
    assert json.loads(out)["held"] is False


def test_lease_tokens_never_start_with_a_dash():
    # token_urlsafe starts with "-" once in 32 leases; argparse then reads `--lease <it>` as an option
    from lidard.api.control import new_lease_token
    clock = FakeClock()
    lock = ControlLock(ttl_s=10.0, clock=clock)
    tokens = set()
    for _ in range(200):
        t = lock.acquire("a").token
        lock.release(t)
        tokens.add(t)
        assert re.fullmatch(r"[0-9a-f]{48}", t), t      # 192 random bits, hex: no "-" anywhere
    assert len(tokens) == 200
    assert re.fullmatch(r"[0-9a-f]{48}", new_lease_token())


def test_lidarctl_accepts_a_lease_that_starts_with_a_dash(live, capsys, monkeypatch):
    """A daemon that issues "-..." leases (an older one used token_urlsafe) still works with lidarctl
    in both spellings, ``--lease <token>`` and ``--lease=<token>``; ``--lease --json`` stays an error."""
    import json

    from lidard.api import control
    url, inst = live
    monkeypatch.delenv("LIDARD_LEASE", raising=False)
    monkeypatch.setattr(control, "new_lease_token", lambda: "-Zq_9-dash-first-lease-token")
    code, out, err = lidarctl(capsys, "control", "acquire", "--url", url, "--client", "rig", "--json")
    assert code == 0, err
    lease = json.loads(out)["lease"]
    assert lease == "-Zq_9-dash-first-lease-token"
    for spelling in (["--lease", lease], [f"--lease={lease}"]):
        code, out, err = lidarctl(capsys, "scan", "--url", url, "--rows", "0:1", "--cols", "0:2", "--json",
                                  *spelling)
        assert code == 0, (spelling, err)
        assert json.loads(out)["state"] == "done"
    assert len(inst.requests) == 2
    with pytest.raises(SystemExit) as ex:
        lidarctl(capsys, "control", "status", "--url", url, "--lease", "--json")
    assert ex.value.code != 0 and "--lease" in capsys.readouterr().err
    code, out, err = lidarctl(capsys, "control", "release", "--url", url, "--lease", lease)
    assert code == 0 and "free" in out, err


def test_lease_ttl_comes_from_the_config(tmp_path, monkeypatch):
    monkeypatch.setenv("LIDARD__DAEMON__LEASE_TTL_S", "42")
    cfg = load_config()
    assert cfg.daemon.lease_ttl_s == 42.0
    with app_client(tmp_path, cfg=cfg) as c:
        assert c.get("/control").json()["ttl_s"] == 42.0
    monkeypatch.setenv("LIDARD__DAEMON__LEASE_TTL_S", "-1")
    with pytest.raises(ConfigError, match="lease_ttl_s"):
        load_config()
