"""Replay: a simulated run logged by McapLogger goes through the same monitor code again."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import zenoh

from models.eha import simulate
from service.cli import main
from service.log import McapLogger, TruncatedLogWarning, read_log
from service.monitor import Monitor, MonitorConfig
from service.replay import INPUT_KEYS, read_metadata, replay
from service.sim.scenarios import load_scenario
from service.wire.messages import decode_output, mcap_topic
from service.zenoh_util import BoundedQueue, free_port, loopback, make_config, wait_until

N = 400  # samples per actuator (0.4 s at 1 kHz): enough for the filter, quick to run


@pytest.fixture(scope="module")
def run_rows() -> list[dict]:
    sc = load_scenario("leak_step")
    r = simulate(sc, "HF", out_every=10)  # 1 kHz samples of the HF bench
    rng = np.random.default_rng(7)
    rows = []
    for k in range(N):
        d = {"seq": k, "t": float(r.t[k])}
        for c in ("x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr"):
            d[c] = float(getattr(r, c)[k])
        d["x_j"] += float(rng.normal(0, 50e-6))
        d["p1"] += float(rng.normal(0, 50e3))
        rows.append(d)
    return rows


def _log(path: Path, rows: list[dict], actuators=("elevator_L",), **kw) -> Path:
    with McapLogger(path, chunk_size=16_384, background_flush=False, **kw) as lg:
        for d in rows:
            for act in actuators:
                lg.log(mcap_topic("AC001", act, "meas"), d["t"], d)
    return path


def _direct(rows: list[dict]) -> list:
    mon = Monitor(MonitorConfig())
    outs = [mon.update({k: d[k] for k in INPUT_KEYS}) for d in rows]
    return [o for o in outs if o is not None]


def test_replay_matches_direct_monitor_and_is_repeatable(tmp_path, run_rows):
    log = _log(tmp_path / "live.mcap", run_rows, actuators=("elevator_L", "aileron_R"))
    s1 = replay(log, out=tmp_path / "r1.mcap")
    s2 = replay(log, out=tmp_path / "r2.mcap")
    assert s1.samples == 2 * N and s1.skipped == 0 and not s1.truncated
    assert s1.actuators == ["AC001/elevator_L", "AC001/aileron_R"]
    direct = _direct(run_rows)
    assert s1.outputs == 2 * len(direct)
    for name in s1.actuators:  # interleaved actuators, batched: same numbers as alone
        assert s1.final[name]["est"] == direct[-1].est
        assert s1.final[name]["health"] == direct[-1].health
        assert s1.final[name]["t"] == run_rows[-1]["t"]
    assert s1.final == s2.final and s1.alarms == s2.alarms
    r1 = [(t, x, m) for t, x, m in read_log(tmp_path / "r1.mcap")]
    r2 = [(t, x, m) for t, x, m in read_log(tmp_path / "r2.mcap")]
    assert r1 == r2
    est = [m for t, _, m in r1 if t == "/fleet/AC001/elevator_L/est"]
    assert len(est) == len(direct)
    assert est[-1]["c_lk"] == direct[-1].est["c_lk"]  # JSON floats round-trip exactly
    meas = [m for t, _, m in r1 if t == "/fleet/AC001/elevator_L/meas"]
    assert meas == run_rows
    assert {t.rsplit("/", 1)[1] for t, _, _ in r1} >= {"meas", "est", "residual", "health"}
    md = read_metadata(tmp_path / "r1.mcap")
    assert md["source"] == "replay" and "monitor_config" in md and "baseline" in md
    # the replay's own log replays to the same estimates (config taken from its metadata)
    s3 = replay(tmp_path / "r1.mcap")
    assert s3.final == s1.final
    assert s1.duration_s == pytest.approx(run_rows[-1]["t"] - run_rows[0]["t"])
    assert s1.speed is not None and s1.speed > 0


def test_truncated_log_replays_with_warning(tmp_path, run_rows):
    log = _log(tmp_path / "live.mcap", run_rows)
    full = list(read_log(log))
    cut = tmp_path / "cut.mcap"
    shutil.copyfile(log, cut)
    with open(cut, "r+b") as f:
        f.truncate(log.stat().st_size // 2)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        s = replay(cut)
    assert not [x for x in w if issubclass(x.category, TruncatedLogWarning)]  # in the summary
    assert s.truncated and len(s.warnings) == 1 and "truncated" in s.warnings[0]
    assert 0 < s.samples < len(full)
    direct = _direct(run_rows[: s.samples])
    assert s.final["AC001/elevator_L"]["est"] == direct[-1].est


def test_out_of_order_and_foreign_topics_skipped(tmp_path, run_rows):
    p = tmp_path / "odd.mcap"
    rows = run_rows[:50]
    with McapLogger(p, background_flush=False) as lg:
        for d in rows:
            lg.log(mcap_topic("AC001", "elevator_L", "meas"), d["t"], d)
            lg.log("/fleet/AC001/elevator_L/est", d["t"], {"c_lk": 1.0})
        lg.log(mcap_topic("AC001", "elevator_L", "meas"), rows[10]["t"], rows[10])
        lg.log("/other/topic", 1.0, {"x": 1})
    s = replay(p)
    assert s.samples == 50 and s.skipped == 1
    assert s.final["AC001/elevator_L"]["est"] == _direct(rows)[-1].est


def test_replay_republishes_on_zenoh(tmp_path, run_rows):
    log = _log(tmp_path / "live.mcap", run_rows[:100])
    port = free_port()
    with (
        zenoh.open(make_config("router", listen=[loopback(port)])),
        zenoh.open(make_config("client", connect=[loopback(port)])) as watcher,
        zenoh.open(make_config("client", connect=[loopback(port)])) as pub,
    ):
        q: BoundedQueue[tuple[str, bytes, str]] = BoundedQueue(10_000)
        watcher.declare_subscriber(
            "fleet/AC001/elevator_L/*",
            lambda s: q.put((str(s.key_expr), s.payload.to_bytes(), str(s.encoding))),
        )
        assert wait_until(
            lambda: pub.put("fleet/AC001/elevator_L/probe", b"{}") or len(q) > 0, timeout=10
        )
        q.get_batch(10_000, timeout=0)
        s = replay(log, publish=pub, publish_every=10)
        n = s.outputs // 10
        assert s.published == n and n > 0
        assert wait_until(lambda: len(q) >= 3 * n, timeout=10)  # (+ late probes)
        got = [x for x in q.get_batch(10_000, timeout=0.2) if not x[0].endswith("/probe")]
    keys = sorted({k for k, _, _ in got})
    assert keys == [f"fleet/AC001/elevator_L/{x}" for x in ("est", "health", "res")]
    assert {e for k, _, e in got if k.endswith("/est")} == {
        "application/protobuf;servowatch.EstOutput"
    }
    last_est = [decode_output("est", p) for k, p, _ in got if k.endswith("/est")][-1]
    assert last_est["c_lk"] == s.final["AC001/elevator_L"]["est"]["c_lk"]


def test_cli_json_summary(tmp_path, run_rows, capsys):
    log = _log(tmp_path / "live.mcap", run_rows[:100])
    assert main(["replay", str(log), "--json", "--out", str(tmp_path / "o.mcap")]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["samples"] == 100 and d["actuators"] == ["AC001/elevator_L"]
    assert d["final"]["AC001/elevator_L"]["t"] == run_rows[99]["t"]
    assert (tmp_path / "o.mcap").exists()
    assert main(["replay", str(tmp_path / "nope.mcap")]) == 2
    with pytest.raises(SystemExit):
        main(["replay", str(log), "--speed", "0"])
    with pytest.raises(ValueError):
        replay(log, speed=-1.0)


def test_rotation_set_replays_as_one_log(tmp_path, run_rows):
    rows = run_rows[:200]
    base = tmp_path / "rot.mcap"
    kw = {"rotate_bytes": 8_000, "chunk_size": 2_000, "compression": "none"}
    with McapLogger(base, background_flush=False, **kw) as lg:
        for d in rows:
            lg.log(mcap_topic("AC001", "elevator_L", "meas"), d["t"], d)
    assert len(lg.paths) >= 3 and not base.exists()
    s = replay(base)
    assert s.files == [str(p) for p in lg.paths]
    assert s.samples == 200 and not s.truncated
    assert s.final["AC001/elevator_L"]["est"] == _direct(rows)[-1].est


def test_paced_replay_takes_at_least_the_scaled_duration(tmp_path, run_rows):
    rows = run_rows[:101]  # 0.1 s of data
    log = _log(tmp_path / "live.mcap", rows)
    s = replay(log, speed=0.5)  # half real time: at least 0.2 s
    assert s.samples == 101
    assert s.wall_s >= 0.1 / 0.5 * 0.95
    assert s.final["AC001/elevator_L"]["est"] == _direct(rows)[-1].est


def test_log_every_decimates_outputs_not_estimates(tmp_path, run_rows):
    rows = run_rows[:100]
    log = _log(tmp_path / "live.mcap", rows)
    s = replay(log, out=tmp_path / "dec.mcap", log_every=7)
    got = [(t, m) for t, _, m in read_log(tmp_path / "dec.mcap")]
    est = [m for t, m in got if t.endswith("/est")]
    n_ev = sum(1 for t, _ in got if t.endswith("/events"))
    assert len([m for t, m in got if t.endswith("/meas")]) == 100  # every sample kept
    assert 100 // 7 <= len(est) <= 100 // 7 + n_ev
    direct = _direct(rows)
    assert est[0] == direct[6].est  # the 7th output
    assert s.final["AC001/elevator_L"]["est"] == direct[-1].est
    with pytest.raises(ValueError):
        replay(log, log_every=0)


def test_actuators_appearing_late_grow_the_bank_safely(tmp_path, run_rows):
    """Ten actuators that join one after another (the bank grows past its initial 8 rows
    while the pipelined monitor runs): each ends with the estimates of its own samples."""
    p = tmp_path / "late.mcap"
    starts = {f"act{k}": 30 * k for k in range(10)}
    with McapLogger(p, chunk_size=8_192, background_flush=False) as lg:
        for j, d in enumerate(run_rows):
            for act, j0 in starts.items():
                if j >= j0:
                    lg.log(mcap_topic("AC001", act, "meas"), d["t"], d)
    s = replay(p)
    assert s.samples == sum(N - j0 for j0 in starts.values())
    for act, j0 in starts.items():
        assert s.final[f"AC001/{act}"]["est"] == _direct(run_rows[j0:])[-1].est
