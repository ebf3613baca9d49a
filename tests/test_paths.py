"""Where state lives (issue 54): the config search order (flag, $SERVOWATCH_CONFIG, the user's
config directory, /etc/servowatch/) used by every command, the store and the logs resolved
from it, and the commands saying which store they read."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

from service.paths import DEFAULT_STORE, find_config, store_of, user_config


def _toml(p: Path, text: str) -> Path:
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text)
    return p


def test_the_search_order(tmp_path):
    user = _toml(tmp_path / "xdg" / "servowatch" / "servowatch.toml", 'station = "u"\n')
    flag = _toml(tmp_path / "flag.toml", 'station = "f"\n')
    envf = _toml(tmp_path / "env.toml", 'station = "e"\n')
    env = {"XDG_CONFIG_HOME": str(tmp_path / "xdg"), "SERVOWATCH_CONFIG": str(envf)}
    assert find_config(flag, env) == (flag, "--config")
    assert find_config(None, env) == (envf, "$SERVOWATCH_CONFIG")
    env.pop("SERVOWATCH_CONFIG")
    assert find_config(None, env) == (user, "the user's config")
    user.unlink()
    path, where = find_config(None, env)  # the system's, if this machine has one
    assert where in ("the system's config", "defaults")
    assert user_config({"HOME": "/home/x"}) == Path("/home/x/.config/servowatch/servowatch.toml")
    # a file named by the flag or the variable must exist: returned, the reader says why not
    assert find_config(tmp_path / "none.toml", env)[0] == tmp_path / "none.toml"


def test_the_store_comes_from_the_flag_the_variable_the_config_the_default(tmp_path):
    cfg = _toml(tmp_path / "c.toml", f'store = "{tmp_path / "cfg.sqlite"}"\n')
    env = {"SERVOWATCH_CONFIG": str(cfg), "HOME": str(tmp_path)}
    assert store_of("x.sqlite", env) == ("x.sqlite", "--store")
    assert store_of(None, {**env, "SERVOWATCH_STORE": "e.sqlite"}) == (
        "e.sqlite",
        "$SERVOWATCH_STORE",
    )
    assert store_of(None, env) == (str(tmp_path / "cfg.sqlite"), f"$SERVOWATCH_CONFIG {cfg}")
    empty = {"HOME": str(tmp_path), "XDG_CONFIG_HOME": str(tmp_path / "none")}
    if find_config(None, empty)[0] is None:
        assert store_of(None, empty) == (str(DEFAULT_STORE), "the default")


def test_a_zenoh_command_reads_the_users_config(tmp_path, monkeypatch):
    from service.cli.args import service_config_from_args

    _toml(tmp_path / "servowatch" / "servowatch.toml",
          'station = "userstation"\nlog_dir = "/srv/sw/logs"\n[log]\nkeep_days = 3.0\n')  # fmt: skip
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    monkeypatch.delenv("SERVOWATCH_CONFIG", raising=False)
    ns = argparse.Namespace(config=None, connect=None, listen=None, mode=None,
                            tls_root_ca=None, tls_cert=None, tls_key=None)  # fmt: skip
    cfg = service_config_from_args(ns)
    assert cfg.station == "userstation" and cfg.log_dir == Path("/srv/sw/logs")
    assert cfg.log.keep_days == 3.0


def test_fleet_reads_the_store_the_config_names_and_says_so(tmp_path):
    from service.store import open_store

    store = tmp_path / "fromcfg.sqlite"
    with open_store(store) as s:
        s.add_baseline("AC9/x", {"c_lk": 1e-12}, "test")
    cfg = _toml(tmp_path / "c.toml", f'store = "{store}"\n')
    env = {k: v for k, v in os.environ.items() if k != "SERVOWATCH_STORE"}
    env.update(SERVOWATCH_CONFIG=str(cfg), HOME=str(tmp_path))
    r = subprocess.run([sys.executable, "-m", "service.cli", "fleet"], capture_output=True,
                       text=True, env=env, timeout=120, cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"1 actuator in {store}"), r.stdout


@pytest.mark.parametrize("bad", ["missing.toml"])
def test_a_config_named_but_missing_is_an_error_naming_it(tmp_path, bad):
    env = {k: v for k, v in os.environ.items()}
    env["SERVOWATCH_CONFIG"] = str(tmp_path / bad)
    r = subprocess.run([sys.executable, "-m", "service.cli", "status", "--timeout", "0.1"],
                       capture_output=True, text=True, env=env, timeout=120)  # fmt: skip
    assert r.returncode == 2 and bad in r.stderr and "cannot read" in r.stderr, r.stderr
