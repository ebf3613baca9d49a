"""The shipped single-host config (deploy/loopback/servowatch.toml) runs as a normal user:
its logs go to a folder relative to the working directory, created on start."""

from __future__ import annotations

import re
from pathlib import Path

from service.config import load_config
from service.daemon import Daemon

ROOT = Path(__file__).resolve().parents[1]
TOML = ROOT / "deploy" / "loopback" / "servowatch.toml"


def test_logs_under_the_working_directory(tmp_path, monkeypatch):
    cfg = load_config(TOML, environ={})
    assert not cfg.log_dir.is_absolute() and cfg.log_dir == Path("servowatch-data/logs")
    monkeypatch.chdir(tmp_path)
    d = Daemon(cfg.model_copy(update={"store": "off"}), log_process=False, gather_s=0)
    try:
        assert d.log_path.resolve().parent == tmp_path / "servowatch-data" / "logs"
    finally:
        d.stop()
    assert list((tmp_path / "servowatch-data" / "logs").glob("servowatch-ground1-0-*.mcap"))


def test_commented_metrics_table_is_valid(tmp_path):
    """The example [metrics] table, uncommented, loads: loopback 127.0.0.1:9464."""
    text = TOML.read_text()
    block = re.search(r"^# \[metrics\].*?(?=^\s*$)", text, re.M | re.S)
    assert block, "no [metrics] example"
    lines = [re.sub(r"^# ?", "", ln).split("#")[0].rstrip() for ln in block[0].splitlines()]
    p = tmp_path / "m.toml"
    p.write_text("\n".join(lines) + "\n")
    m = load_config(p, environ={}).metrics
    assert m is not None and m.host_port() == ("127.0.0.1", 9464) and not m.allow_remote
