"""Service settings: defaults, TOML, environment overrides, errors naming field and source."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from service.config import ConfigError, ServiceConfig, load_config
from service.monitor import MonitorConfig


def test_defaults_need_no_file():
    c = load_config(None, environ={})
    assert c == ServiceConfig()
    assert c.station == "ground1" and c.shard == "0"
    assert c.key_expr == "fleet/**/meas"
    assert c.zenoh.mode == "peer" and c.zenoh.connect == ["tcp/127.0.0.1:7447"]
    assert c.zenoh.listen == []
    assert c.flush_s == 1.0 and c.publish_every >= 1 and c.baseline is None
    assert isinstance(c.monitor, MonitorConfig)
    zc = c.zenoh.to_zenoh()
    assert zc.get_json("scouting/multicast/enabled") == "false"


def test_toml_file(tmp_path: Path):
    p = tmp_path / "s.toml"
    p.write_text(
        'station = "ground2"\nshard = "east"\nflush_s = 0.5\nrotate_s = 60\n'
        'log_dir = "/var/log/sw"\n'
        '[zenoh]\nmode = "client"\nconnect = ["tcp/127.0.0.1:7448"]\n'
        "[monitor]\nmax_gap_s = 0.1\n"
    )
    c = load_config(p, environ={})
    assert (c.station, c.shard, c.flush_s, c.rotate_s) == ("ground2", "east", 0.5, 60.0)
    assert c.log_dir == Path("/var/log/sw")
    assert c.zenoh.mode == "client" and c.zenoh.connect == ["tcp/127.0.0.1:7448"]
    assert c.monitor.max_gap_s == 0.1


def test_environment_overrides_file(tmp_path: Path):
    p = tmp_path / "s.toml"
    p.write_text('station = "file"\nflush_s = 0.5\n')
    env = {
        "SERVOWATCH_STATION": "env",
        "SERVOWATCH_ZENOH__CONNECT": "tcp/127.0.0.1:1, tcp/127.0.0.1:2",
        "SERVOWATCH_ZENOH__LISTEN": '["tcp/127.0.0.1:3"]',
        "SERVOWATCH_ROTATE_BYTES": "null",
        "SERVOWATCH_PUBLISH_EVERY": "5",
        "SERVOWATCH_MONITOR__MAX_GAP_S": "0.2",
        "SERVOWATCH_SOMETHING_ELSE": "ignored",
        "OTHER": "x",
    }
    c = load_config(p, environ=env)
    assert c.station == "env"
    assert c.flush_s == 0.5
    assert c.zenoh.connect == ["tcp/127.0.0.1:1", "tcp/127.0.0.1:2"]
    assert c.zenoh.listen == ["tcp/127.0.0.1:3"]
    assert c.rotate_bytes is None and c.publish_every == 5
    assert c.monitor.max_gap_s == 0.2


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("flush_s = -1\n", "flush_s"),
        ("statoin = 'x'\n", "statoin"),
        ("station = 'a/b'\n", "station"),
        ("[zenoh]\nconnect = ['tcp/10.1.2.3:7447']\n", "zenoh.connect"),
        ("[zenoh]\nlisten = ['tcp/0.0.0.0:7447']\n", "zenoh.listen"),
        ("[zenoh]\nmode = 'client'\nconnect = []\n", "zenoh"),
        ("[zenoh]\nmode = 'bridge'\n", "zenoh.mode"),
        ("[monitor]\nmax_gap_s = -1\n", "monitor.max_gap_s"),
        ("publish_every = 0\n", "publish_every"),
    ],
)
def test_file_errors_name_field_and_file(tmp_path: Path, text: str, field: str):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as ei:
        load_config(p, environ={})
    assert ei.value.field == field
    assert ei.value.source == str(p)
    assert str(p) in str(ei.value) and field in str(ei.value)


def test_remote_endpoints_need_allow_remote(tmp_path: Path):
    p = tmp_path / "remote.toml"
    p.write_text("[zenoh]\nallow_remote = true\nconnect = ['tcp/10.1.2.3:7447']\n")
    assert load_config(p, environ={}).zenoh.connect == ["tcp/10.1.2.3:7447"]


def test_env_errors_name_the_variable():
    with pytest.raises(ConfigError) as ei:
        load_config(None, environ={"SERVOWATCH_FLUSH_S": "fast"})
    assert ei.value.source == "SERVOWATCH_FLUSH_S" and ei.value.field == "flush_s"
    with pytest.raises(ConfigError) as ei:
        load_config(None, environ={"SERVOWATCH_ZENOH__CONNECT": "tcp/192.168.0.1:7447"})
    assert ei.value.source == "SERVOWATCH_ZENOH__CONNECT"
    assert ei.value.field == "zenoh.connect"


def test_unreadable_or_invalid_toml(tmp_path: Path):
    with pytest.raises(ConfigError) as ei:
        load_config(tmp_path / "missing.toml", environ={})
    assert "missing.toml" in str(ei.value)
    p = tmp_path / "broken.toml"
    p.write_text("station = \n")
    with pytest.raises(ConfigError) as ei:
        load_config(p, environ={})
    assert "broken.toml" in str(ei.value) and "TOML" in str(ei.value)


# --------------------------------------------------------------------------- TLS settings


def _pem(tmp_path: Path, *names: str) -> dict[str, str]:
    out = {}
    for n in names:
        (tmp_path / f"{n}.pem").write_text("not checked here\n")
        out[n] = str(tmp_path / f"{n}.pem")
    return out


def test_tls_paths_from_file_env_and_into_zenoh(tmp_path: Path):
    f = _pem(tmp_path, "ca", "cert", "key")
    p = tmp_path / "s.toml"
    p.write_text(
        "[zenoh]\nmode = 'client'\nconnect = ['tls/127.0.0.1:7447']\n"
        f"[zenoh.tls]\nroot_ca = '{f['ca']}'\ncert = '{f['cert']}'\nkey = '{f['key']}'\n"
    )
    c = load_config(p, environ={})
    assert c.zenoh.tls.root_ca == Path(f["ca"]) and c.zenoh.connect == ["tls/127.0.0.1:7447"]
    zc = c.zenoh.to_zenoh()
    assert json.loads(zc.get_json("transport/link/tls/root_ca_certificate")) == f["ca"]
    assert json.loads(zc.get_json("transport/link/tls/connect_certificate")) == f["cert"]
    assert json.loads(zc.get_json("transport/link/tls/connect_private_key")) == f["key"]
    assert zc.get_json("transport/link/tls/enable_mtls") == "true"
    g = _pem(tmp_path / "..", "other")
    env = {"SERVOWATCH_ZENOH__TLS__CERT": g["other"], "SERVOWATCH_ZENOH__TLS__KEY": g["other"]}
    c = load_config(p, environ=env)
    assert c.zenoh.tls.cert == Path(g["other"]) and c.zenoh.tls.root_ca == Path(f["ca"])


def test_tls_errors_name_the_field(tmp_path: Path):
    f = _pem(tmp_path, "ca", "cert")
    with pytest.raises(ConfigError) as ei:  # a tls/ endpoint without the CA
        load_config(None, environ={"SERVOWATCH_ZENOH__CONNECT": "tls/127.0.0.1:7447"})
    assert "tls.root_ca" in str(ei.value)
    with pytest.raises(ConfigError) as ei:
        load_config(None, environ={"SERVOWATCH_ZENOH__TLS__ROOT_CA": str(tmp_path / "no.pem")})
    assert ei.value.field == "zenoh.tls.root_ca"
    assert ei.value.source == "SERVOWATCH_ZENOH__TLS__ROOT_CA" and "no such file" in str(ei.value)
    p = tmp_path / "s.toml"
    p.write_text(f"[zenoh.tls]\nroot_ca = '{f['ca']}'\ncert = '{f['cert']}'\n")
    with pytest.raises(ConfigError) as ei:  # cert without key
        load_config(p, environ={})
    assert ei.value.field == "zenoh.tls" and "together" in str(ei.value)


def test_tls_flags_override(tmp_path: Path):
    import argparse

    from service.cli.args import add_tls_arguments, tls_overrides

    f = _pem(tmp_path, "ca", "cert", "key")
    ap = argparse.ArgumentParser()
    add_tls_arguments(ap)
    args = ap.parse_args(["--tls-root-ca", f["ca"], "--tls-cert", f["cert"], "--tls-key", f["key"]])
    z = tls_overrides(args, load_config(None, environ={}).zenoh.model_dump())
    assert z["tls"] == {"root_ca": f["ca"], "cert": f["cert"], "key": f["key"]}
