"""What the operator reads is the history's truth (issue 49): a log is identified by all of
its samples, one life order serves every view, and the views agree. Real logs of the HF bench
(3 s, 1 kHz) through the real monitor; every case on SQLite and PostgreSQL."""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest

from service.replay import expand_logs, replay, replay_many
from service.store import Period, open_store
from service.store.lifeorder import LogUnit
from tests._store_versions import roll_back

DAY = 86400.0
T0 = 1.75e9  # Unix sample times, as the daemon's logs have
UNIT = "AC1/ail_L"


@pytest.fixture(scope="module")
def meas():
    """3 s of the healthy HF bench with the scenario's sensor noise, 1 kHz."""
    try:
        from service.monitor.calibration import measured_run
        from service.sim.scenarios import load_scenario
    except ImportError:  # the layout before issue 48
        from service.calibration import measured_run
        from service.scenarios import load_scenario

    sc = load_scenario("healthy_noise").model_copy(update={"duration_s": 3.0})
    return measured_run(sc)[1]


def _chans(meas) -> list[str]:
    return [k for k in meas if k != "t"]


def _write(path: Path, t, vals, names, ac="AC1", act="ail_L", record=None) -> Path:
    """An acquisition-style log without a flight record (``record``: with that
    ``FlightRecord``): several chunks (16 KiB), samples logged 250 at a time."""
    from service.log import McapLogger
    from service.log.flightrec import FLIGHT_RECORD

    path.parent.mkdir(parents=True, exist_ok=True)
    t = np.asarray(t, float)
    cols = np.column_stack([t, vals])
    with McapLogger(path, chunk_size=16_384, background_flush=False) as lg:
        if record is not None:
            lg.add_metadata(FLIGHT_RECORD, record.to_metadata())
        for a in range(0, len(t), 250):
            sl = slice(a, a + 250)
            lt = np.nan_to_num(t[sl], nan=0.0)
            lg.log_block(f"/fleet/{ac}/{act}/meas", lt, ("t", *names), cols[sl])
    return path


def _log(path: Path, meas, t0=0.0, k=0, keep=1000, cut=slice(None), t=None) -> Path:
    """The bench's samples from sample time ``t0`` (0: a clock that starts at power-on);
    ``k`` > 0: the same first ``keep`` samples, then samples of another flight (every channel
    moved by ``k`` x 1e-6 of its own scale); ``cut`` a slice of the samples."""
    names = _chans(meas)
    vals = np.column_stack([meas[c] for c in names]).astype(float)
    if k:
        vals[keep:] += k * 1e-6 * (1.0 + np.abs(vals[keep:]))
    tt = meas["t"] + t0 if t is None else np.asarray(t, float)
    return _write(path, tt[cut], vals[cut], names)


def _store(url):
    return open_store(url)


def _snapshot(url) -> str:
    with open_store(url) as s:
        assert s.check() == []
        units = {a: ([p.to_dict() for p in s.periods(a)], [asdict(e) for e in s.alarms(a)])
                 for a in s.actuators()}  # fmt: skip
        fleet = [{k: v for k, v in d.items() if k != "rul_updated_s"} for d in s.fleet_summary()]
    return json.dumps({"units": units, "fleet": fleet}, sort_keys=True, default=str)


def _samples(url, unit=UNIT) -> int:
    with open_store(url) as s:
        return sum(p.samples for p in s.periods(unit))


def _sources(url, unit=UNIT) -> set[str]:
    with open_store(url) as s:
        return {p.source for p in s.periods(unit)}


def _fresh(request, store_url, tmp_path, name):
    """Another empty store of the same backend as ``store_url``."""
    if store_url.startswith("postgresql"):
        return request.getfixturevalue("pg_cluster").create_database()
    return str(tmp_path / f"{name}.sqlite")


# ------------------------------------------------------------------ 1. identity: all samples


def test_three_flights_sharing_a_first_sample_are_three_logs(store_url, tmp_path, meas):
    """Clock at 0 at power-on, the actuator at rest at first: the same first 1000 samples,
    then three different flights. All three are stored, as three flights."""
    n = len(meas["t"])
    logs = [_log(tmp_path / f"flight{k}.mcap", meas, k=k + 1) for k in range(3)]
    out = replay_many(logs, store_url)
    assert [s.stored for s in out] == [{UNIT: "new"}] * 3
    assert len(_sources(store_url)) == 3
    assert _samples(store_url) == 3 * n
    with open_store(store_url) as s:
        assert sorted({p.flight for p in s.periods(UNIT)}) == [0, 1, 2]
        assert s.check() == []


def test_a_shared_prefix_then_other_samples_is_two_logs(store_url, tmp_path, meas):
    n = len(meas["t"])
    a = _log(tmp_path / "a.mcap", meas, T0, k=1)
    b = _log(tmp_path / "b.mcap", meas, T0, k=2)  # the same first 1000 samples, then not
    replay(a, store=store_url)
    s = replay(b, store=store_url)
    assert s.stored == {UNIT: "new"}
    assert any("shares" in w and "both kept" in w for w in s.warnings)
    assert len(_sources(store_url)) == 2 and _samples(store_url) == 2 * n
    # and in the other order the same store
    assert replay(a, store=store_url).stored == {UNIT: "stored"}


def test_a_renamed_copy_changes_nothing_flights_included(store_url, tmp_path, meas):
    logs = [_log(tmp_path / "logs" / f"eha-{k}.mcap", meas, k=k + 1, keep=0) for k in range(8)]
    replay_many(logs, store_url)
    ref = _snapshot(store_url)
    copy = tmp_path / "elsewhere" / "backup_eha.mcap"
    copy.parent.mkdir()
    shutil.copyfile(logs[-1], copy)
    s = replay(copy, store=store_url)
    assert s.stored == {UNIT: "stored"} and s.periods_new == 0
    assert _snapshot(store_url) == ref


def test_a_copy_or_a_rerun_cannot_change_the_flights_of_undated_logs(request, store_url,
                                                                      tmp_path, meas):  # fmt: skip
    logs = [_log(tmp_path / "logs" / f"z{k}.mcap", meas, k=k + 1, keep=0) for k in range(3)]
    replay_many(logs, store_url)
    other = _fresh(request, store_url, tmp_path, "other")
    renamed = []
    for k, p in enumerate(reversed(logs)):  # other names, another order
        q = tmp_path / "renamed" / f"a{k}.mcap"
        q.parent.mkdir(exist_ok=True)
        shutil.copyfile(p, q)
        renamed.append(q)
    replay_many(renamed, other)
    assert _snapshot(other) == _snapshot(store_url)


def _rotation_set(folder: Path, meas, n_files=2) -> tuple[Path, int]:
    names = _chans(meas)
    vals = np.column_stack([meas[c] for c in names]).astype(float)
    t = meas["t"] + T0
    cuts = np.linspace(0, len(t), n_files + 1).astype(int)
    for i in range(n_files):
        sl = slice(cuts[i], cuts[i + 1])
        _write(folder / f"daemon-{i:04d}-20250101T00000{i}.mcap", t[sl], vals[sl], names)
    return folder / "daemon.mcap", len(t)


def test_a_rotation_set_then_its_members_stores_each_sample_once(request, store_url, tmp_path,
                                                                 meas):  # fmt: skip
    base, n = _rotation_set(tmp_path / "set", meas)
    s = replay(base, store=store_url)
    assert s.samples == n and s.stored == {UNIT: "new"}
    out = replay_many(expand_logs([tmp_path / "set"]), store_url)
    assert [o.stored for o in out] == [{UNIT: "stored"}] * 2
    assert _samples(store_url) == n and len(_sources(store_url)) == 1
    # the members first, then the set: the set replaces them, the same store
    other = _fresh(request, store_url, tmp_path, "other")
    replay_many(expand_logs([tmp_path / "set"]), other)
    assert replay(base, store=other).stored == {UNIT: "superseded"}
    assert _snapshot(other) == _snapshot(store_url)


def test_a_trimmed_copy_stores_nothing(store_url, tmp_path, meas):
    log = _log(tmp_path / "full.mcap", meas, T0)
    replay(log, store=store_url)
    ref = _snapshot(store_url)
    trimmed = _log(tmp_path / "copy" / "trimmed.mcap", meas, T0, cut=slice(100, None))
    s = replay(trimmed, store=store_url)
    assert s.stored == {UNIT: "stored"} and s.periods_new == 0
    assert any("stored already" in w for w in s.warnings)
    assert _snapshot(store_url) == ref


# ------------------------------------------------------------------ 2. one life order


def test_a_clock_a_day_back_keeps_the_log_order(store_url, tmp_path, meas):
    """The clock steps back a day mid-log: the periods stay in the log's order, one flight,
    and the latest reading is the one after the step; the next day's log follows."""
    t = meas["t"] + T0
    t[1500:] -= DAY
    log = _log(tmp_path / "clock.mcap", meas, t=t)
    s = replay(log, store=store_url)
    assert s.time[UNIT]["restarts"] == 1
    with open_store(store_url) as st:
        ps = st.periods(UNIT)
        post = max(p.start_t for p in ps if p.start_t < T0)  # after the step, a day "before"
        row = st.fleet_summary()[0]
        assert row["last"]["start_t"] == post
        assert {p.flight for p in ps} == {0}
    nxt = _log(tmp_path / "next.mcap", meas, T0 + DAY)
    replay(nxt, store=store_url)
    with open_store(store_url) as st:
        ps = st.periods(UNIT)
        assert sorted({p.flight for p in ps if p.start_t >= T0 + DAY}) == [1]
        assert {p.flight for p in ps if p.start_t < T0 + DAY} == {0}
        assert st.fleet_summary()[0]["last"]["start_t"] >= T0 + DAY


def _fleet_sim_store(url, ratios, unit=UNIT) -> None:
    """A store as fleet-sim writes it: one log per flight, each with a flight record, every
    period at log time 0 and without calendar time; the logs' content hashes in an order
    other than their flights'."""
    with open_store(url) as s:
        for f, r in enumerate(ratios):
            src = "log:" + hashlib.sha256(f"{unit}{f}".encode()).hexdigest()[:24]
            p = Period(
                actuator=unit, source=src, start_t=0.0, end_t=60.0, op_time_s=60.0,
                samples=60_000, flight=f, c_lk_mean=r * 1e-13, c_lk_sigma=1e-15,
                c_lk_ratio=r, observable_samples=50_000, p_sr_mean=2.07e7, p_sr_min=2.0e7,
                i_b_mean=0.0, nis_mean=1.0, nis_in_band=0.95, alarms=0, bad_samples=0,
                dropped=0,
            )  # fmt: skip
            s.ingest_log([LogUnit(unit, src, 60_000, f"flight-{f:03d}.mcap", False)], [p],
                         [], 1800.0)  # fmt: skip


def test_the_latest_ratio_and_trend_on_a_fleet_sim_store(store_url, capsys):
    """Every period at log time 0 (fleet-sim, and any log whose clock starts at 0): the
    latest reading is the last flight's, the trend follows the flights."""
    from service.cli import main

    ratios = list(np.linspace(1.03, 12.3, 12))
    _fleet_sim_store(store_url, ratios)
    with open_store(store_url) as s:
        row = s.fleet_summary()[0]
        assert row["last"]["c_lk_ratio"] == pytest.approx(12.3)
        assert row["last"]["flight"] == 11
        assert row["trend"]["label"] == "rising"
    capsys.readouterr()
    assert main(["fleet", "--store", store_url, "--json"]) == 0
    fl = json.loads(capsys.readouterr().out)["fleet"][0]
    assert fl["last"]["c_lk_ratio"] == pytest.approx(12.3)
    assert main(["rul", "--store", store_url, "--json"]) == 0
    r = json.loads(capsys.readouterr().out)["actuators"][0]
    assert r["last_ratio"] == pytest.approx(12.3) and r["axis"] == "flights"


def test_a_flight_given_for_a_stored_log_is_applied_with_a_message(store_url, tmp_path, meas):
    log = _log(tmp_path / "f.mcap", meas, k=1)
    replay(log, store=store_url)
    s = replay(log, store=store_url, flight=7, start_unix=T0)
    assert s.stored == {UNIT: "stored"}
    assert any("flight 7" in w and "applied" in w for w in s.warnings)
    with open_store(store_url) as st:
        ps = st.periods(UNIT)
        assert {p.flight for p in ps} == {7}
        assert min(p.start_unix for p in ps) == pytest.approx(T0 + ps[0].start_t - meas["t"][0])


def test_a_copy_with_a_flight_record_gives_the_same_flights_in_either_order(
    request, store_url, tmp_path, meas
):
    """Three dated logs without a flight record, and a copy of the second's samples whose
    record says flight 7 (a recording imported again with ``--flight 7``): the record is
    applied whichever of the two is stored first (before: stored after the plain log, the
    record was dropped, giving flights 0, 1, 2 instead of 0, 7, 8)."""
    from service.log.flightrec import FlightRecord

    names = _chans(meas)
    vals = np.column_stack([meas[c] for c in names]).astype(float)
    plain = [_log(tmp_path / f"d{d}.mcap", meas, T0 + d * DAY, k=d + 1, keep=0) for d in (0, 2, 4)]
    t2 = meas["t"] + T0 + 2 * DAY
    v2 = vals + 3 * 1e-6 * (1.0 + np.abs(vals))  # the samples of d2.mcap (k = 3)
    rec = FlightRecord("AC1", "ail_L", 7, float(t2[0]), float(t2[0]))
    copy7 = _write(tmp_path / "again" / "d2_flight7.mcap", t2, v2, names, record=rec)
    replay_many(plain, store_url)
    s = replay(copy7, store=store_url)
    assert s.stored == {UNIT: "stored"} and s.periods_new == 0
    assert any("flight 7" in w and "applied" in w for w in s.warnings)
    other = _fresh(request, store_url, tmp_path, "other")
    replay(copy7, store=other)
    replay_many(plain, other)
    with open_store(store_url) as st:
        assert [p.flight for p in st.life(UNIT)] == [0, 7, 8]
        assert st.fleet_summary()[0]["flights"] == 3
    assert _snapshot(store_url) == _snapshot(other)


def test_a_log_at_the_calendar_time_of_another_with_other_samples_is_named(store_url,
                                                                           tmp_path, meas):  # fmt: skip
    """The same flight in other samples (another export rate, map or acquisition): no
    sample in common, the same calendar time. Both are kept, as two flights (the gap rule's
    negative gap), and the replay says so, naming the stored log (before: not a word)."""
    a = _log(tmp_path / "rig_1khz.mcap", meas, T0, k=1, keep=0)
    b = _log(tmp_path / "rig_2khz_export.mcap", meas, T0 + 0.5, k=2, keep=0)
    c = _log(tmp_path / "next_day.mcap", meas, T0 + DAY, k=3, keep=0)
    replay(a, store=store_url)
    s = replay(b, store=store_url)
    assert s.stored == {UNIT: "new"}
    (w,) = [w for w in s.warnings if "calendar time" in w]
    assert "overlaps rig_1khz.mcap by 2.5 s of calendar time" in w and "two flights" in w
    s = replay(c, store=store_url)
    assert not [w for w in s.warnings if "calendar time" in w]
    with open_store(store_url) as st:
        assert [p.flight for p in st.life(UNIT)] == [0, 1, 2]


def test_an_undated_log_after_dated_flights_is_named(store_url, tmp_path, meas):
    """A recording imported without its date (sample times from 0, no ``--start-unix``)
    joining a unit with dated flights goes after them in the life order, so it becomes the
    unit's latest reading: the replay says so (before: not a word). A dated log after it,
    and an undated log on an undated history, get no such line."""
    a = _log(tmp_path / "dated.mcap", meas, T0, k=1, keep=0)
    b = _log(tmp_path / "undated.mcap", meas, 0.0, k=2, keep=0)
    c = _log(tmp_path / "next_day.mcap", meas, T0 + DAY, k=3, keep=0)
    d = _log(tmp_path / "undated_2.mcap", meas, 0.0, k=4, keep=0)
    assert not replay(a, store=store_url).warnings
    s = replay(b, store=store_url)
    assert s.stored == {UNIT: "new"}
    (w,) = [w for w in s.warnings if "no calendar time" in w]
    assert "undated.mcap" in w and "latest reading" in w and "--start-unix" in w
    assert not [w for w in replay(c, store=store_url).warnings if "no calendar time" in w]
    with open_store(store_url) as st:
        assert st.life(UNIT)[-1].start_unix is None  # the undated log is latest in life order
    other = str(tmp_path / "undated_only.sqlite")
    assert not [w for w in replay(b, store=other).warnings if "no calendar time" in w]
    assert not [w for w in replay(d, store=other).warnings if "no calendar time" in w]


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_a_batch_shows_the_stores_lines(store_url, tmp_path, meas, capsys, jobs):
    """``replay DIR --store S`` (in process, and on ``--jobs`` workers) prints the store's
    lines as a single replay does, and lists them under ``warnings`` in ``--json`` (before:
    a trimmed copy stored nothing without a word, on either path)."""
    from service.cli import main

    full = _log(tmp_path / "a" / "full.mcap", meas, T0, k=1, keep=0)
    _log(tmp_path / "b" / "trimmed.mcap", meas, T0, k=1, keep=0, cut=slice(0, 2000))
    assert main(["replay", str(full), "--store", store_url]) == 0
    capsys.readouterr()
    args = ["replay", str(tmp_path / "b"), str(tmp_path / "a"), "--store", store_url]
    assert main([*args, "--jobs", jobs, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    (w,) = out["warnings"]
    assert "trimmed.mcap" in w and "every sample of it is stored already, from full.mcap" in w
    assert main([*args, "--jobs", jobs]) == 0
    assert f"  warning: {w}" in capsys.readouterr().out.splitlines()


# ------------------------------------------------------------------ the daemon's log


def test_live_periods_and_a_replay_of_the_daemons_own_log_store_each_sample_once(
    store_url, tmp_path, meas
):
    """The daemon stores its periods live beside its log (its ``log_id``); a catch-up replay
    of that log into the same store replaces them rather than adding the run again."""
    from service.log import McapLogger

    names = _chans(meas)
    vals = np.column_stack([meas[c] for c in names]).astype(float)
    t = meas["t"] + T0
    log = tmp_path / "servowatch-st-0.mcap"
    with McapLogger(log, chunk_size=16_384, background_flush=False,
                    metadata={"source": "daemon", "log_id": "d41d8cd98f00b204"}) as lg:  # fmt: skip
        for a in range(0, len(t), 250):
            lg.log_block("/fleet/AC1/ail_L/meas", t[a : a + 250], ("t", *names),
                         np.column_stack([t, vals])[a : a + 250])  # fmt: skip
    scratch = str(tmp_path / "scratch.sqlite")
    replay(log, store=scratch)
    with open_store(scratch) as s:  # what the daemon stored live, beside that log
        live = [Period.from_dict({**p.to_dict(), "source": "live:st/0@d41d8cd98f00b204"})
                for p in s.periods(UNIT)]  # fmt: skip
    with open_store(store_url) as s:
        s.add_periods(live)
    n = _samples(store_url)
    s = replay(log, store=store_url)
    assert _samples(store_url) == n == len(t)
    assert s.stored == {UNIT: "superseded"}


# ------------------------------------------------------------------ 3. views that agree


def _period(unit, src, start_t, ratio, flight=None, start_unix=None, op=600.0) -> Period:
    return Period(
        actuator=unit, source=src, start_t=start_t, end_t=start_t + op, op_time_s=op,
        samples=int(op * 1000), flight=flight, c_lk_mean=ratio * 1e-13, c_lk_sigma=1e-15,
        c_lk_ratio=ratio, observable_samples=int(op * 800), p_sr_mean=2.07e7, p_sr_min=2.0e7,
        i_b_mean=0.0, nis_mean=1.0, nis_in_band=0.95, alarms=0, bad_samples=0, dropped=0,
        start_unix=start_unix,
    )  # fmt: skip


def _src(*parts) -> str:
    return "log:" + hashlib.sha256(repr(parts).encode()).hexdigest()[:32]


def _views_store(url) -> None:
    """Units stored each way of issue 49: fleet-sim logs (log time 0, flight records) past
    the threshold and below it; undated logs without records (gap rule); dated logs; a
    log whose clock stepped back a day; the daemon's live periods."""
    ratios = np.linspace(1.03, 12.3, 10)
    with open_store(url) as s:
        for unit, rs in (("SIM/failed", ratios), ("SIM/healthy", np.full(10, 1.02))):
            for f, r in enumerate(rs):
                src = _src(unit, f)
                s.ingest_log([LogUnit(unit, src, 1, f"f{f}.mcap", False)],
                             [_period(unit, src, 0.0, float(r), flight=f)], [], 1800.0)  # fmt: skip
        for k, r in enumerate(np.linspace(1.0, 3.0, 10)):  # undated, no records
            src = _src("U", k)
            s.ingest_log([LogUnit("UND/eha", src, 1, f"u{k}.mcap", True)],
                         [_period("UND/eha", src, 0.0, float(r))], [], 1800.0)  # fmt: skip
        for k, r in enumerate(np.linspace(1.0, 2.0, 10)):  # dated, one a day
            src = _src("D", k)
            su = T0 + k * DAY
            s.ingest_log([LogUnit("DAT/eha", src, 1, f"d{k}.mcap", True)],
                         [_period("DAT/eha", src, su, float(r), start_unix=su)], [], 1800.0)  # fmt: skip
        src = _src("C")  # one log: the clock a day back after its first period
        ps = [_period("CLK/eha", src, T0 + 600.0 * i - (DAY if i >= 5 else 0.0), 1.0 + 0.05 * i,
                      start_unix=T0 + 600.0 * i - (DAY if i >= 5 else 0.0)) for i in range(10)]  # fmt: skip
        order = tuple(p.start_t for p in ps)
        s.ingest_log([LogUnit("CLK/eha", src, 1, "c.mcap", True, order=order)], ps, [], 1800.0)
        s.add_periods([_period("LIV/eha", "live:st/0", T0 + k * DAY, 1.0 + 0.02 * k, flight=k,
                               start_unix=T0 + k * DAY) for k in range(10)])  # fmt: skip


def test_views_agree(store_url, capsys):
    """fleet (text and JSON), the page's fleet and unit JSON, rul, status and the metrics show
    the same latest ratio, life axis, RUL and trend for every unit, and the unit past its
    failure threshold is failed in every view."""
    from service.cli import main
    from service.cli.commands.status import format_unit
    from service.edge.fleet import condition_of
    from service.edge.metrics import collect_status
    from service.edge.web.view import fleet_view, unit_view
    from service.store.writer import StoreWriter

    _views_store(store_url)
    capsys.readouterr()
    assert main(["rul", "--store", store_url, "--json"]) == 0
    rul = {r["actuator"]: r for r in json.loads(capsys.readouterr().out)["actuators"]}
    assert main(["fleet", "--store", store_url, "--json"]) == 0
    fleet = {r["actuator"]: r for r in json.loads(capsys.readouterr().out)["fleet"]}
    assert main(["fleet", "--store", store_url]) == 0
    text = capsys.readouterr().out
    with open_store(store_url, read_only=True) as s:
        page = {r["actuator"]: r for r in fleet_view(s)["fleet"]}
        units = {a: unit_view(s, a) for a in s.actuators()}
        w = StoreWriter.__new__(StoreWriter)
        w._load(s)
        info = w._info
    assert len(fleet) == 6
    with_rul = {
        a
        for a, r in rul.items()
        if r.get(f"median_{'flights' if r['axis'] == 'flights' else 'h'}") is not None
    }  # noqa: E501
    assert {
        a for a, r in fleet.items() if (r["rul_interval"] or {}).get("median") is not None
    } == with_rul
    assert {
        a for a, r in page.items() if (r["rul_interval"] or {}).get("median") is not None
    } == with_rul
    for a in fleet:
        f, p, r, u = fleet[a], page[a], rul[a], units[a]
        last_u = [x["c_lk_ratio"] for x in u["periods"] if x["c_lk_ratio"] is not None][-1]
        assert f["last_ratio"] == p["last_ratio"] == pytest.approx(r["last_ratio"]) == \
            pytest.approx(last_u), a  # fmt: skip
        axis = "flights" if r["axis"] == "flights" else "h"
        assert f["life"]["unit"] == p["life"]["unit"] == axis, a
        assert f["life"]["value"] == pytest.approx(r["t_now"] if axis == "flights"
                                                   else r["t_now_h"]), a  # fmt: skip
        # the page's unit chart: the same axis, its last period where `rul` says it stands
        assert u["life_axis"] == ("flights" if axis == "flights" else "hours"), a
        assert u["periods"][-1]["life"] == pytest.approx(r["t_now"]), a
        assert f["trend"] == p["trend"], a
        med = r.get(f"median_{axis}")
        assert (f["rul_interval"] or {}).get("median") == pytest.approx(med) if med is not None \
            else (f["rul_interval"] or {}).get("median") is None  # fmt: skip
        cond = condition_of(f)
        assert condition_of(p) == cond == condition_of({**info[a], "actuator": a}), a
        st_unit = {"aircraft": a.split("/")[0], "actuator": a.split("/")[1], "samples": 1,
                   "dropped": 0, "gaps": 0, **info[a]}  # fmt: skip
        lines = "\n".join(format_unit(st_unit))
        fams = {m.name: m for m in collect_status({"actuators": {a: st_unit}})}
        failed = [s.value for s in fams["servowatch_unit_failed"].samples]
        if cond[0] == "failed":
            assert p["status"] == "critical" and r["status"] == "failed", a
            assert "FAILED" in lines and failed == [1.0], a
            assert any(a in ln and "FAILED" in ln for ln in text.splitlines()), a
        else:
            assert "FAILED" not in lines and failed == [0.0], a
    assert condition_of(fleet["SIM/failed"])[0] == "failed"
    assert fleet["SIM/failed"]["last_ratio"] == pytest.approx(12.3)
    assert fleet["SIM/healthy"]["last_ratio"] == pytest.approx(1.02)
    assert fleet["CLK/eha"]["last_ratio"] == pytest.approx(1.45)
    assert fleet["UND/eha"]["life"]["unit"] == "flights"


# ------------------------------------------------------------------ 5. migration 7


def _as_before_v7(url) -> None:
    """The store as servowatch wrote it before schema v7: no stream identities, no sample
    order, no life-order summary columns, its summary's latest period by ``start_t`` (and
    nothing of the migrations after 7)."""
    with open_store(url) as s, s._b.transaction():
        b = s._b
        roll_back(b, 6)
        for (a,) in b.execute("SELECT name FROM actuators").fetchall():
            last = b.execute("SELECT start_t, source FROM periods WHERE actuator = ? "
                             "ORDER BY start_t DESC, source DESC LIMIT 1", (a,)).fetchone()  # fmt: skip
            p = [q for q in s.periods(a) if (q.start_t, q.source) == (last[0], last[1])][0]
            b.execute("UPDATE summary SET last_period = ? WHERE actuator = ?",
                      (json.dumps(p.to_dict()), a))  # fmt: skip


def test_migration_7_reorders_an_old_store_without_its_logs(store_url):
    """A fleet-sim store written before v7 read its latest period by source hash; opening
    it migrates it and the summary follows the life order, no log at hand."""
    ratios = list(np.linspace(1.03, 12.3, 12))
    _fleet_sim_store(store_url, ratios)
    _as_before_v7(store_url)
    with open_store(store_url, create=False) as s:  # a writer's open migrates
        from service.store.schema import LATEST_VERSION

        assert s.schema_version() == LATEST_VERSION
        row = s.fleet_summary()[0]
        assert row["last"]["flight"] == 11 and row["last_ratio"] == pytest.approx(12.3)
        assert row["life_axis"] == "flights" and s.check() == []


def test_migration_7_adopts_an_old_log_when_it_is_replayed(store_url, tmp_path, meas):
    """A log stored before v7 (its first-sample id, no stream identity) is re-identified
    when it is replayed again: the same periods under its new source, nothing twice."""
    from service.replay.input import unit_source
    from service.wire import messages as m

    log = _log(tmp_path / "old.mcap", meas, T0)
    replay(log, store=store_url)
    ref = _snapshot(store_url)
    with open_store(store_url) as s:
        (p,) = s.periods(UNIT)[:1]
        new_src = p.source
    ch0 = np.array([meas[c][0] if c in meas else np.nan for c in m.CHANNELS])
    old_src = unit_source(UNIT, float(meas["t"][0] + T0), ch0)  # the id before v7
    _as_before_v7(store_url)
    with open_store(store_url) as s, s._b.transaction():
        for t in ("periods", "alarms", "log_sources"):
            s._b.execute(f"UPDATE {t} SET source = ?", (old_src,))
    with open_store(store_url) as s:
        assert {q.source for q in s.periods(UNIT)} == {old_src}
    s2 = replay(log, store=store_url)
    assert s2.stored == {UNIT: "superseded"}
    assert _snapshot(store_url) == ref and _sources(store_url) == {new_src}
