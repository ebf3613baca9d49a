"""Ingest that ordinary operations cannot corrupt (issue 40): a log's identity is its content,
flight numbers are a function of the logs alone (any split, re-run or crash gives the store of
one clean run), every bad file is named while the rest goes in, corrupt chunks are skipped,
time is checked by the daemon's intake rules, ``--jobs`` workers die with their parent.
Real logs of the HF bench (3 s each) through the real monitor; SQLite and PostgreSQL."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest

from service.cli import main
from service.log import McapLogger
from service.replay import replay, replay_many
from service.store import open_store

ROOT = Path(__file__).resolve().parents[1]
DAY = 86400.0
T0 = 1.75e9  # Unix sample times, as the daemon's logs have
# (day, minute) of each flight's log: two logs 10 min apart are one flight (gap rule, 30 min)
SLOTS = [(0, 0), (0, 10), (1, 0), (2, 0), (2, 10), (3, 0), (5, 0), (6, 0)]


@pytest.fixture(scope="module")
def meas():
    """3 s of the healthy HF bench with the scenario's sensor noise, 1 kHz."""
    from service.monitor.calibration import measured_run
    from service.sim.scenarios import load_scenario

    sc = load_scenario("healthy_noise").model_copy(update={"duration_s": 3.0})
    return measured_run(sc)[1]


def _log(path: Path, meas, t0: float, ac="AC1", act="ail_L", n=None, seq=False, t=None) -> Path:
    """An acquisition-style log without a flight record, several chunks (16 KiB), samples
    logged 250 at a time; ``t`` replaces the sample times."""
    chans = [k for k in meas if k != "t"]
    tt = meas["t"] + t0 if t is None else np.asarray(t, float)
    n = len(tt) if n is None else n
    names = ("seq", "t", *chans) if seq else ("t", *chans)
    cols = ([np.arange(n, dtype=float)] if seq else []) + [tt[:n]] + [meas[c][:n] for c in chans]
    vals = np.column_stack(cols)
    with McapLogger(path, chunk_size=16_384, background_flush=False) as lg:
        for a in range(0, n, 250):
            sl = slice(a, a + 250)
            lt = np.nan_to_num(tt[:n][sl], nan=0.0, posinf=0.0, neginf=0.0)
            lg.log_block(f"/fleet/{ac}/{act}/meas", lt, names, vals[sl])
    return path


def _fleet_logs(folder: Path, meas) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for k, (d, mi) in enumerate(SLOTS):
        out.append(_log(folder / f"ac1-{k:02d}.mcap", meas, T0 + d * DAY + mi * 60))
    return out


def _snapshot(url) -> str:
    """Periods, flights, alarms and the fleet rows (wall-clock fields removed) as text."""
    with open_store(url) as s:
        assert s.check() == []
        units = {a: ([p.to_dict() for p in s.periods(a)], [asdict(e) for e in s.alarms(a)])
                 for a in s.actuators()}  # fmt: skip
        fleet = [{k: v for k, v in d.items() if k != "rul_updated_s"} for d in s.fleet_summary()]
    return json.dumps({"units": units, "fleet": fleet}, sort_keys=True, default=str)


def _flights(url, unit="AC1/ail_L") -> list:
    with open_store(url) as s:
        return [p.flight for p in s.periods(unit)]


def _rul_json(url, capsys) -> dict:
    capsys.readouterr()
    assert main(["rul", "--store", str(url), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)

    def strip(x):
        if isinstance(x, dict):
            return {
                k: strip(v)
                for k, v in x.items()
                if k not in ("wall_s", "updated_s", "rul_updated_s", "store")
            }
        if isinstance(x, list):
            return [strip(v) for v in x]
        return x

    return strip(out)


def _fresh(request, store_url, tmp_path, name):
    """Another empty store of the same backend as ``store_url``."""
    if store_url.startswith("postgresql"):
        return request.getfixturevalue("pg_cluster").create_database()
    return str(tmp_path / f"{name}.sqlite")


# -------------------------------------------------------------- 2. flights from the logs


def test_flights_are_a_function_of_the_logs_in_any_split(request, store_url, tmp_path, meas,
                                                          capsys):  # fmt: skip
    logs = _fleet_logs(tmp_path / "logs", meas)
    clean = _fresh(request, store_url, tmp_path, "clean")
    replay_many(logs, clean)
    # flights by the gap rule over the calendar: (0,0),(0,10) one flight, then one a day
    assert sorted(set(_flights(clean))) == [0, 1, 2, 3, 4, 5]
    ref = _snapshot(clean)
    # the documented way to add new logs: the folder again, old and new together
    replay_many(logs[:5], store_url)
    replay_many(logs, store_url)
    assert _snapshot(store_url) == ref
    # any split, any order, and the same batch twice
    other = _fresh(request, store_url, tmp_path, "split")
    for part in (logs[6:], logs[2:4], logs[::-1], logs[:3]):
        replay_many(part, other)
    assert _snapshot(other) == ref
    assert _rul_json(other, capsys) == _rul_json(clean, capsys)


def test_a_copy_is_one_source_a_grown_log_supersedes_its_partial_ingest(tmp_path, meas):
    logs = _fleet_logs(tmp_path / "logs", meas)
    clean = tmp_path / "clean.sqlite"
    replay_many(logs, clean)
    ref = _snapshot(clean)
    store = tmp_path / "h.sqlite"
    # the last log copied while it was still written: its first half, no footer
    part = tmp_path / "in-progress" / logs[-1].name
    part.parent.mkdir()
    part.write_bytes(logs[-1].read_bytes()[: logs[-1].stat().st_size // 2])
    replay_many([*logs[:-1], part], store)
    s_part = replay(part, store=store)
    assert s_part.periods_new == 0
    # then complete: its period is replaced, not added, and no new flight is counted
    s = replay(logs[-1], store=store)
    assert _snapshot(store) == ref
    assert s.stored == {"AC1/ail_L": "superseded"} and s_part.stored == {"AC1/ail_L": "stored"}
    # the partial copy once more changes nothing (the longer ingest stays)
    assert replay(part, store=store).stored == {"AC1/ail_L": "stored"}
    # a byte-identical copy under another name: the same source, nothing stored twice
    copy = tmp_path / "elsewhere" / "renamed.mcap"
    copy.parent.mkdir()
    shutil.copyfile(logs[3], copy)
    s = replay(copy, store=store)
    assert s.stored == {"AC1/ail_L": "stored"} and s.periods_new == 0
    assert _snapshot(store) == ref


def _corrupt_middle_chunk(src: Path, dst: Path) -> int:
    """``dst``: ``src`` with one byte of its middle chunk's data flipped; returns the chunk
    count."""
    from mcap.reader import make_reader

    with open(src, "rb") as fh:
        idx = make_reader(fh).get_summary().chunk_indexes
    ci = idx[len(idx) // 2]
    data = bytearray(src.read_bytes())
    data[ci.chunk_start_offset + ci.chunk_length // 2] ^= 0xFF
    dst.write_bytes(bytes(data))
    return len(idx)


def test_corrupt_chunk_is_skipped_and_the_repaired_log_supersedes(tmp_path, meas, capsys):
    good = _log(tmp_path / "good.mcap", meas, T0)
    bad = tmp_path / "damaged" / "good.mcap"
    bad.parent.mkdir()
    chunks = _corrupt_middle_chunk(good, bad)
    assert chunks >= 5
    n = len(meas["t"])
    store = tmp_path / "h.sqlite"
    s = replay(bad, store=store)
    # one chunk lost, every intact chunk after it read
    assert n - 2 * n // chunks <= s.samples < n and s.corrupt_chunks == 1
    assert s.t_end == pytest.approx(meas["t"][-1] + T0)
    assert any("corrupt chunk" in w for w in s.warnings)
    capsys.readouterr()
    assert main(["replay", str(bad), "--store", str(tmp_path / "x.sqlite"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["corrupt_chunks"] == 1
    # the repaired log supersedes the damaged ingest (it was skipped as already seen)
    s2 = replay(good, store=store)
    assert s2.samples == n and s2.stored == {"AC1/ail_L": "superseded"}
    clean = tmp_path / "clean.sqlite"
    replay(good, store=clean)
    assert _snapshot(store) == _snapshot(clean)


# ---------------------------------------------------------------- 4. bad files named


def test_every_bad_file_is_named_and_the_good_ones_go_in(tmp_path, meas, capsys):
    from service.log.flightrec import FLIGHT_RECORD

    folder = tmp_path / "batch"
    folder.mkdir()
    good = [_log(folder / f"g{k}.mcap", meas, T0 + k * DAY) for k in range(2)]
    (folder / "empty.mcap").write_bytes(b"")
    (folder / "text.mcap").write_text("flight 12, all good\n")
    (folder / "random.mcap").write_bytes(np.random.default_rng(1).bytes(5000))
    (folder / "header.mcap").write_bytes(good[0].read_bytes()[:40])
    for name, flight in (("badrec.mcap", "twelve"), ("huge.mcap", "9" * 30)):
        with McapLogger(folder / name, background_flush=False) as lg:
            lg.add_metadata(FLIGHT_RECORD, {"aircraft": "AC1", "actuator": "ail_L",
                                            "flight": flight})  # fmt: skip
            ch = [k for k in meas if k != "t"]
            lg.log_block(
                "/fleet/AC1/ail_L/meas",
                meas["t"] + T0 + 9 * DAY,
                ("t", *ch),
                np.column_stack([meas["t"] + T0 + 9 * DAY] + [meas[c] for c in ch]),
            )
    bad = {"empty", "text", "random", "header", "badrec", "huge"}
    store = tmp_path / "h.sqlite"
    capsys.readouterr()
    rc = main(["replay", str(folder), "--store", str(store), "--json"])
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert rc == 1
    assert {Path(f["log"]).stem for f in out["failed"]} == bad
    for f in out["failed"]:  # one line each, naming the file and the cause
        assert f["error"].startswith(f["log"]) and "\n" not in f["error"]
    assert "Traceback" not in cap.err
    assert "twelve" in next(f["error"] for f in out["failed"] if "badrec" in f["log"])
    with open_store(store) as s:
        assert s.count_periods("AC1/ail_L") == 2  # the good logs went in
    # the text summary lists them too
    rc = main(["replay", str(folder), "--store", str(store)])
    text = capsys.readouterr().out
    assert rc == 1 and sum(line.startswith("  failed: ") for line in text.splitlines()) == 6
    # one bad log alone: one line, exit 2
    for name in sorted(bad):
        rc = main(["replay", str(folder / f"{name}.mcap"), "--store", str(store)])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and f"{name}.mcap" in err[0], (name, err)


def test_store_failure_mid_batch_is_one_line_with_what_was_stored(tmp_path, meas, capsys,
                                                                monkeypatch):  # fmt: skip
    """The store fails with SQLite's SQLITE_FULL (a full disk) at the second log's write."""
    import sqlite3

    from service.store import health

    logs = _fleet_logs(tmp_path / "logs", meas)[:3]
    store = tmp_path / "h.sqlite"
    real = health._SQLite.bulk_insert
    calls = []

    def full(self, table, *a, **kw):
        calls.append(table)
        if calls.count("periods") > 1:
            raise sqlite3.OperationalError("database or disk is full")
        return real(self, table, *a, **kw)

    monkeypatch.setattr(health._SQLite, "bulk_insert", full)
    capsys.readouterr()
    rc = main(["replay", *map(str, logs), "--store", str(store), "--json"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 5 and len(err) == 1, err
    assert str(store) in err[0] and "full" in err[0] and "stored so far: 1 of 3 logs" in err[0]
    monkeypatch.undo()
    with open_store(store) as s:
        assert s.check() == [] and s.count_periods() == 1


# ------------------------------------------------------------------- 5. time checked


def test_a_clock_that_steps_back_is_followed_not_the_rest_dropped(tmp_path, meas, capsys):
    n = len(meas["t"])
    t = meas["t"] + T0
    t[n // 2 :] -= 2.0  # the clock steps back 2 s mid-log (an NTP correction)
    log = _log(tmp_path / "step.mcap", meas, T0, t=t)
    s = replay(log, store=tmp_path / "h.sqlite")
    # the daemon's rule: refused until resync_n (5) consistent samples, then followed
    assert s.samples == n - 5 and s.skipped == 5
    tc = s.time["AC1/ail_L"]
    assert tc["clock"] == 5 and tc["restarts"] == 1
    assert any("time checks" in w for w in s.warnings)
    with open_store(tmp_path / "h.sqlite") as st:
        ps = st.periods("AC1/ail_L")
    assert len(ps) == 2 and sum(p.samples for p in ps) == n - 5  # one before, one after
    capsys.readouterr()
    assert main(["replay", str(log), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["time"]["AC1/ail_L"]["restarts"] == 1


def test_duplicate_constant_and_non_finite_times_are_counted(tmp_path, meas, capsys):
    n = len(meas["t"])
    t = meas["t"] + T0
    t[100:110] = t[99]  # ten repeats of one time
    t[200] = np.nan
    t[300] = np.inf
    dup = _log(tmp_path / "dup.mcap", meas, T0, t=t)
    s = replay(dup)
    tc = s.time["AC1/ail_L"]
    assert tc["duplicate"] == 10 and tc["non_finite"] == 2 and tc["restarts"] == 0
    assert s.samples == n - 12
    const = _log(tmp_path / "const.mcap", meas, T0, t=np.full(n, T0))
    folder = tmp_path / "b"
    folder.mkdir()
    shutil.copyfile(const, folder / "const.mcap")
    shutil.copyfile(dup, folder / "dup.mcap")
    capsys.readouterr()
    assert main(["replay", str(folder), "--store", str(tmp_path / "h.sqlite"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    by = {Path(c["log"]).stem: c for c in out["time_checks"]}
    assert by["const"]["duplicate"] == n - 1 and by["dup"]["duplicate"] == 10
    assert main(["replay", str(folder), "--store", str(tmp_path / "h.sqlite")]) == 0
    text = capsys.readouterr().out
    assert f"duplicate {n - 1}" in text and "const.mcap" in text


def test_a_logged_seq_judges_forward_jumps_as_the_daemon_does(tmp_path, meas):
    t = meas["t"] + T0
    t[1000] += 50.0  # one sample 50 s ahead of what its sequence number allows
    log = _log(tmp_path / "ahead.mcap", meas, T0, seq=True, t=t)
    s = replay(log)
    assert s.samples == len(t) - 1  # that sample only, not the rest of the log
    tc = s.time["AC1/ail_L"]
    assert tc["clock"] == 1 and tc["restarts"] == 0


# ----------------------------------------------------------- 2. killed batch, re-run


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "service.cli", *args]


def _stored_logs(url) -> int:
    try:
        with open_store(url) as s:
            return int(s._b.execute("SELECT COUNT(*) FROM log_sources").fetchone()[0])
    except Exception:
        return 0


@pytest.mark.slow
def test_a_batch_killed_at_several_points_then_rerun_equals_a_clean_run(request, store_url,
                                                                        tmp_path, meas):  # fmt: skip
    folder = tmp_path / "logs"
    logs = _fleet_logs(folder, meas)
    clean = _fresh(request, store_url, tmp_path, "clean")
    replay_many(logs, clean)
    ref = _snapshot(clean)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    killed_at = []
    for k in (1, 3, 6):  # kill -9 once this many logs are stored, then run it again
        p = subprocess.Popen(_cli("replay", str(folder), "--store", store_url, "--json"),
                             cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)  # fmt: skip
        end = time.monotonic() + 120
        while _stored_logs(store_url) < k and p.poll() is None and time.monotonic() < end:
            time.sleep(0.02)
        p.send_signal(signal.SIGKILL)
        p.wait()
        killed_at.append(_stored_logs(store_url))
        with open_store(store_url) as s:
            assert s.check() == []
    assert killed_at[0] < len(logs)  # killed mid-batch at least once
    r = subprocess.run(_cli("replay", str(folder), "--store", store_url, "--json"), cwd=ROOT,
                       env=env, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert _snapshot(store_url) == ref


# ------------------------------------------------------------ 6. --jobs with its parent


def _children(pid: int) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(d.name))
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_jobs_workers_die_with_a_killed_parent(tmp_path, meas):
    folder = tmp_path / "logs"
    folder.mkdir()
    for k in range(5):
        for act in ("ail_L", "ail_R", "elev"):
            _log(folder / f"{act}-{k:02d}.mcap", meas, T0 + k * DAY, act=act)
    store = tmp_path / "h.sqlite"
    p = subprocess.Popen(_cli("replay", str(folder), "--store", str(store), "--jobs", "2"),
                         cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    end = time.monotonic() + 120
    workers: list[int] = []
    while time.monotonic() < end and p.poll() is None:
        workers = _children(p.pid)
        if len(workers) >= 2 and _stored_logs(store) >= 1:
            break
        time.sleep(0.05)
    assert p.poll() is None and len(workers) >= 2
    p.send_signal(signal.SIGKILL)
    p.wait()
    end = time.monotonic() + 10
    while time.monotonic() < end and any(_alive(w) for w in workers):
        time.sleep(0.05)
    assert not [w for w in workers if _alive(w)]
    n = _stored_logs(store)
    time.sleep(1.0)
    assert _stored_logs(store) == n < 15  # killed mid-batch, and nothing writes any more


@pytest.mark.slow
def test_jobs_name_a_bad_file_and_store_the_rest(tmp_path, meas, capsys):
    folder = tmp_path / "logs"
    folder.mkdir()
    for k in range(2):
        for act in ("ail_L", "ail_R"):
            _log(folder / f"{act}-{k}.mcap", meas, T0 + k * DAY, act=act)
    (folder / "notes.mcap").write_text("not a log\n")
    store = tmp_path / "h.sqlite"
    capsys.readouterr()
    rc = main(["replay", str(folder), "--store", str(store), "--jobs", "2", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 1 and [Path(f["log"]).name for f in out["failed"]] == ["notes.mcap"]
    assert out["failed"][0]["error"].startswith(str(folder / "notes.mcap"))
    assert out["actuators"] == {
        "AC1/ail_L": {"flights": 2, "first": 0, "last": 1},
        "AC1/ail_R": {"flights": 2, "first": 0, "last": 1},
    }


def test_a_log_stored_before_schema_v4_is_adopted_not_stored_twice(tmp_path, meas):
    """A store written by the previous servowatch holds the log under ``log:{name}:{hash}``
    and has no ``log_sources`` row: replaying the log again replaces those periods."""
    from service.replay import legacy_log_source

    log = _log(tmp_path / "old.mcap", meas, T0)
    store = tmp_path / "h.sqlite"
    replay(log, store=store)
    ref = _snapshot(store)
    old = legacy_log_source([log])
    with open_store(store) as s, s._b.transaction():  # as the previous version stored it
        s._b.execute("DELETE FROM log_sources")
        s._b.execute("UPDATE periods SET source = ?", (old,))
        s._b.execute("UPDATE alarms SET source = ?", (old,))
    with open_store(store) as s:
        assert {p.source for p in s.periods("AC1/ail_L")} == {old}
    s2 = replay(log, store=store)
    assert s2.stored == {"AC1/ail_L": "superseded"}
    assert _snapshot(store) == ref
