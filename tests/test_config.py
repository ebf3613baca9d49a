"""Service settings: defaults, TOML, environment overrides, errors naming field and source."""

from __future__ import annotations

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
