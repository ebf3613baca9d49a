"""The loopback rule for every command and every way of giving endpoints (issue 33, item 3).

``servowatch router`` checks the endpoints of its final config (flags and ``--config``
alike, and Zenoh's own default listen ``tcp/[::]:7447`` when a config names none); the
service commands check ``[zenoh]`` from the TOML, the ``SERVOWATCH_ZENOH__*`` variables and
the flags. A non-loopback listen without TLS needs ``allow_plain_listen`` on top of
``allow_remote``. Nothing here listens off loopback: every refusal happens before the
session opens, and the addresses are 0.0.0.0 (checked in-process, never opened) or
192.0.2.1 (TEST-NET-1, assigned to no host: a command that did try would fail to bind).
"""

from __future__ import annotations

import argparse
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from service.config import ConfigError, load_config
from service.zenoh_util import EndpointError, check_endpoint, free_port

ROOT = Path(__file__).resolve().parents[1]
SECURE = ROOT / "deploy" / "secure"
NOWHERE = "192.0.2.1"  # TEST-NET-1 (RFC 5737): no host has it, nothing can bind it


def _router_args(*argv: str) -> argparse.Namespace:
    from service.cli.commands import router

    p = argparse.ArgumentParser()
    router.add_arguments(p)
    return p.parse_args(list(argv))


def _cli(*argv: str, env: dict | None = None, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "service.cli", *argv], capture_output=True, text=True,
        timeout=timeout, cwd=ROOT, env={**os.environ, **(env or {})},
    )  # fmt: skip


@pytest.mark.parametrize(
    "argv",
    [
        ["--config", str(SECURE / "router.json5"), "--listen", "tcp/0.0.0.0:7447"],
        ["--config", str(ROOT / "deploy" / "loopback" / "router.json5"), "--listen",
         "tcp/0.0.0.0:7447"],
        ["--config", str(SECURE / "router.json5"), "--connect", "tls/10.0.0.5:7447"],
        ["--listen", "tcp/0.0.0.0:7447", "--allow-remote"],  # plain tcp/ needs its own flag
    ],
)  # fmt: skip
def test_router_config_endpoints_are_checked(argv):
    """In-process (nothing is opened): the final config's endpoints are refused."""
    from service.cli.commands.router import _config

    with pytest.raises(EndpointError, match="refused"):
        _config(_router_args(*argv))


def test_router_config_without_listen_is_not_every_interface(tmp_path):
    """A config naming no listen endpoint would get Zenoh's default, tcp/[::]:7447."""
    from service.cli.commands.router import _config

    cfg = tmp_path / "r.json5"
    cfg.write_text('{ mode: "router", scouting: { multicast: { enabled: false } } }')
    with pytest.raises(EndpointError, match=r"\[::\]"):
        _config(_router_args("--config", str(cfg)))


def test_router_remote_tls_listen_with_allow_remote_passes_the_check():
    from service.cli.commands.router import _config

    _, listen = _config(
        _router_args("--config", str(SECURE / "router.json5"), "--listen", "tls/0.0.0.0:7447",
                     "--allow-remote")
    )  # fmt: skip
    assert listen == ["tls/0.0.0.0:7447"]


def test_router_command_with_config_exits_2_before_listening():
    port = free_port()
    res = _cli(
        "router", "--config", str(SECURE / "router.json5"), "--listen", f"tcp/{NOWHERE}:{port}"
    )
    assert res.returncode == 2, res
    assert "refused" in res.stderr and f"{NOWHERE}:{port}" in res.stderr
    assert "listening on" not in res.stderr and res.stdout == ""


def test_plain_remote_listen_needs_its_flag_and_warns(caplog):
    ep = "tcp/10.0.0.5:7447"
    with pytest.raises(EndpointError, match="plain"):
        check_endpoint(ep, allow_remote=True, listen=True)
    assert check_endpoint(ep, allow_remote=True) == ep  # a connect endpoint: no TLS rule
    assert check_endpoint("tls/10.0.0.5:7447", allow_remote=True, listen=True)
    with caplog.at_level(logging.WARNING, logger="service.zenoh_util"):
        assert check_endpoint(ep, allow_remote=True, listen=True, allow_plain_listen=True) == ep
    assert any("without TLS" in r.getMessage() for r in caplog.records)


def test_environment_listen_follows_the_rule(tmp_path):
    env = {"SERVOWATCH_ZENOH__ALLOW_REMOTE": "true", "SERVOWATCH_ZENOH__LISTEN": "tcp/0.0.0.0:7447"}
    with pytest.raises(ConfigError, match="plain"):
        load_config(environ=env)
    with pytest.raises(ConfigError, match="refused"):
        load_config(environ={"SERVOWATCH_ZENOH__LISTEN": "tcp/0.0.0.0:7447"})
    cfg = load_config(environ={**env, "SERVOWATCH_ZENOH__ALLOW_PLAIN_LISTEN": "true"})
    assert cfg.zenoh.listen == ["tcp/0.0.0.0:7447"]


@pytest.mark.parametrize("how", ["flag", "env", "toml"])
def test_service_command_refuses_remote_plain_listen(tmp_path, how):
    """``servowatch status`` (any service command): exit 2 before opening a session."""
    ep = f"tcp/{NOWHERE}:{free_port()}"
    args, env = ["status", "--timeout", "1"], {}
    if how == "flag":
        args += ["--listen", ep, "--mode", "peer"]
        env["SERVOWATCH_ZENOH__ALLOW_REMOTE"] = "true"
    elif how == "env":
        env.update(SERVOWATCH_ZENOH__ALLOW_REMOTE="true", SERVOWATCH_ZENOH__LISTEN=ep)
    else:
        toml = tmp_path / "c.toml"
        toml.write_text(f'[zenoh]\nallow_remote = true\nmode = "peer"\nlisten = ["{ep}"]\n')
        args += ["--config", str(toml)]
    res = _cli(*args, env=env)
    assert res.returncode == 2, res
    assert "plain" in res.stderr


@pytest.mark.skipif(__import__("shutil").which("openssl") is None, reason="needs openssl")
def test_certificate_validity_tells_not_yet_valid_from_expired(tmp_path):
    """A not-yet-valid certificate is not reported as expired (TLS sends one alert for both)."""
    import time

    from service.zenoh_util import certificate_validity

    subprocess.run(["bash", str(ROOT / "deploy" / "pki" / "make-certs.sh"), str(tmp_path), "operator"],
                   check=True, capture_output=True, timeout=60)  # fmt: skip
    pem = tmp_path / "operator.pem"
    now = time.time()
    assert certificate_validity(pem, now) == ""
    assert certificate_validity(pem, now - 2 * 86400).startswith("not yet valid (from ")
    assert certificate_validity(pem, now + 400 * 86400).startswith("expired (on ")
    assert certificate_validity(tmp_path / "nothing.pem") == ""


@pytest.mark.skipif(__import__("shutil").which("openssl") is None, reason="needs openssl")
def test_daemon_warns_when_its_certificate_is_another_identity(tmp_path, caplog):
    from service.cli.commands.run import _check_identity
    from service.zenoh_util import certificate_cn

    subprocess.run(["bash", str(ROOT / "deploy" / "pki" / "make-certs.sh"), str(tmp_path),
                    "monitor.ground1.0", "monitor.ground1.1"],
                   check=True, capture_output=True, timeout=60)  # fmt: skip
    assert certificate_cn(tmp_path / "monitor.ground1.1.pem") == "monitor.ground1.1"
    env = {"SERVOWATCH_ZENOH__TLS__ROOT_CA": str(tmp_path / "ca.pem"),
           "SERVOWATCH_ZENOH__TLS__CERT": str(tmp_path / "monitor.ground1.1.pem"),
           "SERVOWATCH_ZENOH__TLS__KEY": str(tmp_path / "monitor.ground1.1.key")}  # fmt: skip
    with caplog.at_level(logging.WARNING, logger="servowatch.daemon"):
        _check_identity(load_config(environ=env))  # station ground1, shard 0
        assert "not 'monitor.ground1.0'" in caplog.text
        caplog.clear()
        _check_identity(load_config(environ={**env, "SERVOWATCH_SHARD": "1"}))
        assert caplog.text == ""
