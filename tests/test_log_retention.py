"""Retention of the daemon's logs (issue 54, decision 0041): the oldest closed files go
first, by their calendar end; never the open file, never a file a reader or an ingest
holds; what was deleted is counted and listed."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from service.log import McapLogger, read_log
from service.log.retention import Retention, hold, pattern_of

DAY = 86400.0
NOW = 1.8e9


def _file(d: Path, name: str, size: int, end: float) -> Path:
    p = d / name
    p.write_bytes(b"\0" * size)
    os.utime(p, (end, end))
    return p


def _names(r: Retention) -> list[str]:
    return [p.name for p, _, _ in r.files()]


def test_keep_bytes_deletes_the_oldest_end_first_not_the_name_order(tmp_path):
    pre = "servowatch-ground1-0-"
    # the names sort the other way round from their ends: order comes from the end time
    _file(tmp_path, pre + "c.mcap", 1000, NOW - 300)
    _file(tmp_path, pre + "b.mcap", 1000, NOW - 200)
    _file(tmp_path, pre + "a.mcap", 1000, NOW - 100)
    _file(tmp_path, "servowatch-ground1-1-x.mcap", 5000, NOW - 900)  # another daemon's
    r = Retention(tmp_path, pattern_of("", pre), keep_bytes=2500)
    done = r.sweep(now=NOW)
    assert [Path(d.path).name for d in done] == [pre + "c.mcap"]
    assert _names(r) == [pre + "b.mcap", pre + "a.mcap"]
    assert (tmp_path / "servowatch-ground1-1-x.mcap").exists()
    st = r.status()
    assert st["deleted_files"] == 1 and st["deleted_bytes"] == 1000
    assert st["kept_files"] == 2 and st["kept_bytes"] == 2000
    assert st["last_deleted"][0]["reason"] == "keep_bytes"
    assert st["last_deleted"][0]["end"] == "2027-01-15T07:55:00.000Z"  # RFC 3339, UTC


def test_keep_days_deletes_what_ended_before_the_cutoff(tmp_path):
    pre = "sw-"
    _file(tmp_path, pre + "1.mcap", 10, NOW - 8 * DAY)
    _file(tmp_path, pre + "2.mcap", 10, NOW - 6.9 * DAY)
    _file(tmp_path, pre + "3.mcap", 10, NOW - 1)
    r = Retention(tmp_path, pattern_of("", pre), keep_days=7)
    done = r.sweep(now=NOW)
    assert [Path(d.path).name for d in done] == [pre + "1.mcap"]
    assert done[0].reason == "keep_days"
    assert _names(r) == [pre + "2.mcap", pre + "3.mcap"]


def test_never_the_open_file_even_when_it_alone_is_over_the_limit(tmp_path):
    pre = "sw-"
    old = _file(tmp_path, pre + "old.mcap", 100, NOW - 10 * DAY)
    cur = _file(tmp_path, pre + "cur.mcap", 5000, NOW - 20 * DAY)  # oldest and biggest
    r = Retention(tmp_path, pattern_of("", pre), keep_bytes=10, keep_days=1)
    r.sweep([cur], now=NOW)
    assert cur.exists() and not old.exists()


def test_a_file_being_read_or_ingested_is_kept_until_released(tmp_path):
    pre = "sw-"
    with McapLogger(tmp_path / f"{pre}a.mcap", background_flush=False, chunk_size=256) as lg:
        for k in range(50):  # 50 chunks: a reader that yielded the first has not read the rest
            lg.log_block("/fleet/AC001/x/meas", np.arange(3.0) + 3 * k, ["p1"], np.ones((3, 1)))
            lg.flush()
    a = tmp_path / f"{pre}a.mcap"
    b = _file(tmp_path, pre + "b.mcap", 10, time.time())
    assert a.stat().st_size > 20
    os.utime(a, (time.time() - 100,) * 2)
    r = Retention(tmp_path, pattern_of("", pre), keep_bytes=20)
    it = read_log(a)
    first = next(it)  # a reader in the middle of the file holds it
    assert r.sweep() == [] and a.exists() and r.busy_skipped == 1
    rest = list(it)
    assert len(rest) + 1 == 150 and first[0] == "/fleet/AC001/x/meas"
    # an ingest in another process holds its whole file set
    code = (
        "import sys, time; from service.log.retention import hold\n"
        "with hold([sys.argv[1]]):\n    print('held', flush=True); time.sleep(30)"
    )
    p = subprocess.Popen([sys.executable, "-c", code, str(a)], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "held"
        assert r.sweep() == [] and a.exists() and r.busy_skipped == 2
    finally:
        p.kill()
        p.wait(10)
    assert [Path(d.path) for d in r.sweep()] == [a] and b.exists()


def test_a_writer_holds_its_file_against_another_processes_sweep(tmp_path):
    pre = "sw-"
    lg = McapLogger(tmp_path / f"{pre}w.mcap", background_flush=False)
    try:
        os.utime(tmp_path / f"{pre}w.mcap", (NOW - 9 * DAY,) * 2)
        r = Retention(tmp_path, pattern_of("", pre), keep_days=1)
        assert r.sweep(now=NOW) == [] and r.busy_skipped == 1  # not told it is open
    finally:
        lg.close()
    assert len(r.sweep(now=NOW)) == 1


def test_hold_skips_missing_files_and_releases(tmp_path):
    a = _file(tmp_path, "sw-a.mcap", 10, NOW - DAY)
    r = Retention(tmp_path, "sw-*.mcap", keep_bytes=1)
    with hold([a, tmp_path / "gone.mcap"]):
        assert r.sweep(now=NOW) == []
    assert len(r.sweep(now=NOW)) == 1


def test_rotation_set_pattern_of_an_explicit_log(tmp_path):
    assert pattern_of(tmp_path / "run.mcap") == "run-[0-9][0-9][0-9][0-9]-*.mcap"
    with pytest.raises(ValueError):
        Retention(tmp_path, "x", keep_bytes=0)


def test_no_limit_deletes_nothing(tmp_path):
    _file(tmp_path, "sw-a.mcap", 10, NOW - 100 * DAY)
    r = Retention(tmp_path, "sw-*.mcap")
    assert r.sweep(now=NOW) == [] and r.status()["kept_files"] == 1


# ------------------------------------------------------------------------- in the daemon


def _meas_payloads(seconds: float, rate: float = 1000.0, per: int = 50) -> list[bytes]:
    from service.sim.actuator import VirtualActuator
    from service.sim.scenarios import load_scenario
    from service.wire import messages as m

    va = VirtualActuator(load_scenario("demo"), rate_hz=rate, t_origin=time.time() - 60, seed=3)
    samples = va.produce(int(seconds * rate))
    return [m.encode_meas(samples[j : j + per]) for j in range(0, len(samples), per)]


def test_the_daemon_keeps_its_logs_within_keep_bytes_and_the_store_its_periods(
    tmp_path, store_url, caplog
):
    from service.config import PrognosticsSettings, ServiceConfig
    from service.daemon import Daemon
    from service.log.settings import LogSettings
    from service.store import open_store

    logs = tmp_path / "logs"
    logs.mkdir()
    now = time.time()
    earlier = _file(logs, "servowatch-ground1-0-20260101T000000Z.mcap", 300_000, now - DAY)
    other = _file(logs, "servowatch-ground2-0-20260101T000000Z.mcap", 300_000, now - DAY)
    cfg = ServiceConfig(
        log_dir=logs, store=store_url, rotate_bytes=60_000, rotate_s=None,
        log=LogSettings(keep_bytes=150_000, keep_days=None, sweep_s=3600),
        prognostics=PrognosticsSettings(period_window_s=0.5),
    )  # fmt: skip
    caplog.set_level(logging.INFO, "servowatch")
    d = Daemon(cfg, log_process=False, gather_s=0)
    d.start()
    assert not earlier.exists() and other.exists()  # an earlier run's file, at the start
    announced = [r.getMessage() for r in caplog.records if r.getMessage().startswith("logging to")]
    # the name announced is the file written (rotated: ...-0000-<time>.mcap), and it exists
    assert announced == [f"logging to {d.outputs.logger.paths[-1]}"]
    assert Path(d.outputs.logger.paths[-1]).exists() and "-0000-" in announced[0]
    payloads = _meas_payloads(4.0)
    for k, p in enumerate(payloads):  # the worker takes them
        d.submit("fleet/AC001/elevator_L/meas", p)
        deadline = time.monotonic() + 30
        while d.queued and time.monotonic() < deadline:
            time.sleep(0.002)
        if k % 10 == 9:
            d.outputs.logger.flush()  # half a second of live data: its chunk written
            d.maybe_sweep(time.monotonic())
            cur = Path(d.outputs.logger.paths[-1])
            assert cur.exists()  # never the open file
    d.outputs.commit()  # the next tick announces a file the last flush rotated to
    st = d.status()
    assert st["log_retention"]["deleted_files"] >= 3  # while it ran
    final = d.stop()
    assert len(d.outputs.logger.paths) >= 5  # rotated often
    again = [r.getMessage() for r in caplog.records if r.getMessage().startswith("logging to")]
    assert len(again) == len(d.outputs.logger.paths)  # each rotated file announced
    d.outputs.sweep_logs()  # stopped: every file closed, the limit holds exactly
    ret = d.outputs.retention.status()
    mine = sorted(logs.glob("servowatch-ground1-0-*.mcap"))
    assert sum(p.stat().st_size for p in mine) == ret["kept_bytes"] <= 150_000
    assert ret["kept_files"] == len(mine) >= 1
    assert not {Path(x["path"]).name for x in ret["last_deleted"]} & {p.name for p in mine}
    gone = [r.getMessage() for r in caplog.records if r.getMessage().startswith("retention:")]
    assert len(gone) == ret["deleted_files"] == len(d.outputs.logger.paths) + 1 - len(mine)
    with open_store(store_url) as s:  # deleted logs delete no history
        ps = s.periods("AC001/elevator_L")
        assert len(ps) >= 7 and sum(p.samples for p in ps) == final["samples"]


ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ["deploy/loopback/servowatch.toml", "deploy/secure/monitor.toml",
           "deploy/two-stations/station-a.toml", "deploy/two-stations/station-b.toml"]  # fmt: skip


@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_daemon_config_sets_a_retention(name):
    import tomllib

    from service.log.settings import LogSettings

    data = tomllib.loads((ROOT / name).read_text())
    lg = LogSettings.model_validate(data["log"])
    assert lg.keep_bytes is not None and lg.keep_days is not None
    assert "keep_bytes" in data["log"] and "keep_days" in data["log"]


def test_without_a_config_the_logs_go_beside_the_default_store():
    from service.config import ServiceConfig
    from service.store import DEFAULT_STORE

    cfg = ServiceConfig()
    assert cfg.log_dir == Path(DEFAULT_STORE).parent / "logs" == Path("servowatch-data/logs")
    assert cfg.log.keep_bytes == 50 * 2**30 and cfg.log.keep_days == 30


def test_status_text_shows_the_log_its_retention_and_the_store():
    from service.cli.commands.status import format_log, format_rul, format_unit

    st = {
        "log": ["/d/servowatch-ground1-0-20261204T095217Z-0003-20261204T125217Z.mcap"],
        "log_retention": {"keep_bytes": 50 * 2**30, "keep_days": 30.0, "kept_files": 1,
                          "kept_bytes": 3 * 2**20, "deleted_files": 2, "deleted_bytes": 5 * 2**30,
                          "last_deleted": [{"path": "/d/a.mcap", "end": "2026-12-04T10:52:19.000Z"}]},
        "store": {"where": "servowatch-data/health.sqlite"},
    }  # fmt: skip
    assert format_log(st) == [
        "  log /d/servowatch-ground1-0-20261204T095217Z-0003-20261204T125217Z.mcap; keeps "
        "50 GiB and 30 d: 1 file (3 MiB) kept, 2 files (5 GiB) deleted, the last /d/a.mcap "
        "(ended 2026-12-04T10:52:19.000Z)",
        "  store servowatch-data/health.sqlite",
    ]
    one = format_unit({"aircraft": "A", "actuator": "b", "periods": 1})[2]
    assert "1 period," in one and "1 periods" not in one
    rul = {"median_flights": 1.2, "lo_flights": 1, "hi_flights": 3, "periods": 5,
           "axis": "flights", "median_days": None}  # fmt: skip
    assert format_rul(rul) == "RUL 1 flight [1-3]"
    assert format_rul({**rul, "median_flights": 2.0}) == "RUL 2 flights [1-3]"
