"""Health store: the same tests on SQLite and PostgreSQL (``store_url`` fixture)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from service.store import AlarmEvent, Period, StoreError, open_store, trend_of
from service.store.schema import LATEST_VERSION, MIGRATIONS

ROOT = Path(__file__).resolve().parents[1]


def make_period(actuator: str, k: int, source: str = "log-a", ratio: float | None = None) -> Period:
    """Period number ``k`` (100 s apart, 90 s long); every field a function of k."""
    r = 1.0 + 0.01 * k if ratio is None else ratio
    return Period(
        actuator=actuator,
        start_t=100.0 * k,
        end_t=100.0 * k + 90.0,
        op_time_s=90.0,
        samples=9000 + k,
        flight=k,
        c_lk_mean=1e-12 * r,
        c_lk_sigma=1e-14,
        c_lk_ratio=r,
        observable_samples=8000,
        p_sr_mean=2.1e7,
        p_sr_min=2.0e7 - k,
        i_b_mean=1e-4,
        nis_mean=1.0,
        nis_in_band=0.95,
        alarms=k % 3,
        bad_samples=k % 2,
        dropped=0,
        source=source,
    )


def test_fresh_store_is_migrated_once(store_url):
    with open_store(store_url) as s:
        assert s.schema_version() == LATEST_VERSION
        s.ensure_actuator("AC001/elevator_L")
    with open_store(store_url) as s:  # reopening applies nothing again and keeps the data
        rows = s._b.execute("SELECT version FROM schema_migrations ORDER BY version").fetchall()
        assert [r[0] for r in rows] == [m[0] for m in MIGRATIONS]
        assert s.actuators() == ["AC001/elevator_L"]


def test_newer_schema_is_refused(store_url):
    with open_store(store_url) as s, s._b.transaction():
        s._b.execute(
            "INSERT INTO schema_migrations (version, description, applied_s) VALUES (?, ?, ?)",
            (LATEST_VERSION + 1, "from the future", 0.0),
        )
    with pytest.raises(StoreError, match=f"schema version {LATEST_VERSION + 1} is newer"):
        open_store(store_url)


def test_baselines_are_versioned(store_url):
    with open_store(store_url) as s:
        assert s.latest_baseline("AC1/ail_L") is None
        r1 = s.add_baseline("AC1/ail_L", {"c_lk": 1.0e-12, "g_pq": 3e9}, "log a", {"wall_s": 2.0})
        r2 = s.add_baseline("AC1/ail_L", {"c_lk": 1.1e-12, "g_pq": 3e9}, "log b", {})
        s.add_baseline("AC2/ail_L", {"c_lk": 0.9e-12}, "scenario healthy", {})
        assert (r1.version, r2.version) == (1, 2)
        latest = s.latest_baseline("AC1/ail_L")
        assert latest is not None
        assert latest.version == 2 and latest.source == "log b"
        assert latest.baseline["c_lk"] == pytest.approx(1.1e-12, rel=0, abs=0)
        assert [(b.actuator, b.version) for b in s.baselines()] == [
            ("AC1/ail_L", 1),
            ("AC1/ail_L", 2),
            ("AC2/ail_L", 1),
        ]
        assert s.baselines("AC1/ail_L")[0].figures == {"wall_s": 2.0}
        fleet = {f["actuator"]: f for f in s.fleet_summary()}
        assert fleet["AC1/ail_L"]["baseline_version"] == 2 and fleet["AC1/ail_L"]["commissioned"]
        s.ensure_actuator("AC3/rud")
        assert s.fleet_summary()[-1]["commissioned"] is False


def test_periods_are_idempotent_and_round_trip(store_url):
    a = "AC001/elevator_L"
    with open_store(store_url) as s:
        assert s.add_periods(make_period(a, k) for k in range(10)) == 10
        # a replay of the same log and more: only the 5 new ones are stored
        assert s.add_periods(make_period(a, k) for k in range(15)) == 5
        assert s.add_period(make_period(a, 3)) is False
        assert s.add_period(make_period(a, 3, source="log-b")) is True  # another source
        got = s.periods(a)
        assert len(got) == 16 and s.count_periods(a) == 16
        assert [p.start_t for p in got] == sorted(p.start_t for p in got)
        assert got[0] == make_period(a, 0)
        assert got[14] == make_period(a, 13)
        # unobservable period: NaN C_Lk and no flight number survive the round trip
        nan_p = Period(a, 5000.0, 5050.0, 50.0, 100, None, math.nan, math.nan, math.nan, 0,
                       2.1e7, 2.1e7, 0.0, 1.0, 1.0, 0, 0, 0, "log-c")  # fmt: skip
        assert s.add_period(nan_p)
        back = s.periods(a)[-1]
        assert back.flight is None and math.isnan(back.c_lk_mean) and math.isnan(back.c_lk_ratio)
        assert s.check() == []


def test_fleet_summary_reads_the_last_period_trend_alarms_and_rul(store_url):
    with open_store(store_url) as s:
        s.add_periods(make_period("AC1/a", k) for k in range(40))  # ratio 1.00 .. 1.39
        s.add_periods(make_period("AC2/b", k, ratio=1.0) for k in range(40))
        s.add_period(make_period("AC1/a", 5, source="late"))  # older period arriving late
        n = s.add_alarms(
            [AlarmEvent("AC1/a", 3950.0, "leak", 1.4e-12, "log-a")] * 2
            + [AlarmEvent("AC1/a", 3960.0, "leak", 1.4e-12, "log-a")]
        )
        assert n == 2
        assert s.add_alarms([AlarmEvent("AC1/a", 3950.0, "leak", 1.4e-12, "log-a")]) == 0
        s.put_rul("AC1/a", {"median_h": 120.0, "lo_h": 80.0, "hi_h": 200.0})
        s.put_rul("AC1/a", {"median_h": 100.0, "lo_h": 70.0, "hi_h": 190.0})
        f = {r["actuator"]: r for r in s.fleet_summary()}
        a, b = f["AC1/a"], f["AC2/b"]
        assert a["periods"] == 41 and a["op_time_s"] == pytest.approx(41 * 90.0)
        assert a["last"]["start_t"] == 3900.0 and a["last"]["c_lk_ratio"] == pytest.approx(1.39)
        # 0.01 per period of 90 s -> 0.4 per operating hour
        assert a["trend"]["label"] == "rising"
        assert a["trend"]["slope_per_h"] == pytest.approx(0.4, rel=0.05)
        assert b["trend"]["label"] == "stable" and b["trend"]["slope_per_h"] == pytest.approx(0)
        assert a["alarms"] == sum(k % 3 for k in range(40)) + 5 % 3
        assert a["alarm_events"] == 2 and a["last_alarm"] == {"t": 3960.0, "kind": "leak"}
        assert a["rul"] == {"median_h": 100.0, "lo_h": 70.0, "hi_h": 190.0}
        assert b["rul"] is None and b["commissioned"] is False
        assert s.check() == []


def test_trend_of_needs_three_observable_periods():
    assert trend_of([[0, 3600, 1.0, 1], [1, 3600, 1.1, 1]])["label"] == "unknown"
    falling = trend_of([[k, 3600, 2.0 - 0.1 * k, 1] for k in range(6)])
    assert falling["label"] == "falling" and falling["slope_per_h"] == pytest.approx(-0.1)
    # unobservable periods are left out of the fit but their operating time counts
    t = trend_of([[0, 3600, 1.0, 1], [1, 3600, math.nan, 0], [2, 3600, 1.2, 1], [3, 3600, 1.3, 1]])
    assert t["periods"] == 3 and t["slope_per_h"] == pytest.approx(0.1)


def test_bad_inputs_name_the_field(store_url):
    with open_store(store_url) as s:
        with pytest.raises(ValueError, match="actuator"):
            s.ensure_actuator("elevator_L")
        with pytest.raises(ValueError, match="baseline"):
            s.add_baseline("AC1/a", {}, "x", {})
        with pytest.raises(TypeError, match="Period"):
            s.add_periods([{"actuator": "AC1/a"}])  # type: ignore[list-item]
    with pytest.raises(ValueError, match="end_t"):
        make_period("AC1/a", 1).__class__(**{**make_period("AC1/a", 1).to_dict(), "end_t": 0.0})
    with pytest.raises(ValueError, match="samples"):
        Period(**{**make_period("AC1/a", 1).to_dict(), "samples": -1})


def test_open_store_rejects_bad_targets(tmp_path):
    with pytest.raises(StoreError, match="unsupported URL scheme 'mysql'"):
        open_store("mysql://u@h/db")
    with pytest.raises(StoreError, match="is a directory"):
        open_store(tmp_path)
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"not a database" * 100)
    with pytest.raises(StoreError, match="junk.sqlite"):
        open_store(junk)
    with pytest.raises(StoreError, match=r"cannot connect to postgresql://u:\*\*\*@127.0.0.1:1/x"):
        open_store("postgresql://u:secret@127.0.0.1:1/x")


_WRITER = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, {tests!r})
    from test_store import make_period
    from service.store import open_store, AlarmEvent
    s = open_store({url!r})
    k = 0
    while True:  # batches of 5 periods for 3 actuators, one transaction each
        s.add_periods(make_period(f"AC{{j}}/act", k + i) for j in range(3) for i in range(5))
        s.add_alarms([AlarmEvent("AC0/act", 100.0 * k, "leak", 1.0, "log-a")])
        k += 5
    """
)


def test_a_writer_killed_with_sigkill_leaves_a_consistent_store(store_url):
    proc = subprocess.Popen(
        [sys.executable, "-c", _WRITER.format(tests=str(ROOT / "tests"), url=store_url)],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    try:
        deadline = time.monotonic() + 60
        with open_store(store_url) as s:
            while s.count_periods() < 600 and time.monotonic() < deadline:
                assert proc.poll() is None, "writer died on its own"
                time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)  # mid-stream: it writes continuously
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    with open_store(store_url) as s:
        assert s.check() == []
        counts = [s.count_periods(f"AC{j}/act") for j in range(3)]
        assert counts[0] >= 600 // 3 - 5
        # each batch is whole: the same number of periods for every actuator, in fives
        assert counts[0] == counts[1] == counts[2] and counts[0] % 5 == 0
        for j in range(3):
            got = s.periods(f"AC{j}/act")
            assert got == [make_period(f"AC{j}/act", k) for k in range(counts[0])]
        assert len(s.alarms("AC0/act")) in (counts[0] // 5, counts[0] // 5 - 1)


def test_migration_2_computes_the_trend_of_a_version_1_store(store_url, monkeypatch):
    import service.store.health as health

    with monkeypatch.context() as m:
        m.setattr(health, "MIGRATIONS", MIGRATIONS[:1])
        m.setattr(health, "LATEST_VERSION", 1)
        with open_store(store_url) as s:
            assert s.schema_version() == 1
            s.ensure_actuator("AC1/a")
            recent = [[100.0 * k, 3600.0, 1.0 + 0.1 * k, 100] for k in range(5)]
            with s._b.transaction():
                s._b.execute("UPDATE summary SET recent = ?", (json.dumps(recent),))
    with open_store(store_url) as s:
        assert s.schema_version() == LATEST_VERSION
        tr = s.fleet_summary()[0]["trend"]
        assert tr["label"] == "rising" and tr["slope_per_h"] == pytest.approx(0.1)
        assert tr["periods"] == 5


def test_read_only_open_never_writes(store_url, tmp_path):
    """``read_only``: the readers' open (the fleet page): no migration, and no write gets
    through, on both backends."""
    from service.store import StoreError

    with open_store(store_url) as s:
        s.add_periods([make_period("AC1/ail_L", k) for k in range(3)])
    with open_store(store_url, read_only=True) as r:
        assert r.count_periods("AC1/ail_L") == 3 and r.read_only
        with pytest.raises(Exception, match="(?i)read.?only|readonly|attempt to write"):
            r.add_periods([make_period("AC1/ail_L", 9)])
    with open_store(store_url) as s:
        assert s.count_periods("AC1/ail_L") == 3  # the refused write left nothing behind
    empty = tmp_path / "empty.sqlite"
    empty.touch()
    with pytest.raises(StoreError, match="not a health store yet"):
        open_store(str(empty), read_only=True)
    assert empty.stat().st_size == 0  # and it was not migrated into one
    with pytest.raises(StoreError, match="does not exist"):
        open_store(str(tmp_path / "none.sqlite"), read_only=True)
