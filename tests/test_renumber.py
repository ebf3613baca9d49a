"""The incremental renumbering (decision record 0044): a store written with it equals one
written with the whole history renumbered on every write, period by period, flight by
flight and summary column by summary column, over randomised arrivals (out of order,
copies, supersedes, ``--flight`` for a stored log, the daemon's live periods and a log
replacing them, another flight gap), on SQLite and PostgreSQL; an append reads no history;
migration 8 keeps an old store and renumbers it whole once."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

import service.store.ingest as ingest_mod
from service.store import AlarmEvent, Period, open_store
from service.store.identity import Relation, Relations, StreamDigest
from service.store.lifeorder import LogUnit
from tests._store_versions import roll_back

UNITS = ("AC1/ail_L", "AC1/elev_R")
DAY = 86400.0


def _period(a: str, t: float, dt: float, rng: random.Random, **kw) -> Period:
    return Period(actuator=a, start_t=t, end_t=t + dt, op_time_s=rng.uniform(1.0, dt),
                  samples=rng.randint(500, 900), flight=kw.pop("flight", 0),
                  c_lk_mean=2e-13, c_lk_sigma=2e-14, c_lk_ratio=rng.uniform(0.9, 3.0),
                  observable_samples=rng.choice((0, 400, 800)), p_sr_mean=2.1e7, p_sr_min=2e7,
                  i_b_mean=0.0, nis_mean=1.0, nis_in_band=0.95, alarms=rng.randint(0, 1),
                  bad_samples=0, dropped=0, source="replay", **_usage(rng), **kw)  # fmt: skip


def _usage(rng: random.Random) -> dict[str, float]:
    if rng.random() < 0.3:  # a period without usage (stored before migration 5)
        return {}
    return {"usage_travel_m": rng.uniform(0.1, 2.0), "usage_reversals": rng.randint(0, 90),
            "usage_loaded_s": rng.uniform(0, 60), "usage_pressurised_s": rng.uniform(0, 60),
            "usage_load_travel_j": rng.uniform(0, 9e3), "usage_load2_travel_n2m": 1e7}  # fmt: skip


class _Log:
    """One replayed log of one unit as the replay hands it to ``ingest_logs``."""

    def __init__(self, a, src, periods, alarms, gap, rng, **kw):
        self.a, self.src, self.periods, self.alarms, self.gap = a, src, periods, alarms, gap
        d = StreamDigest()
        d.add(np.array([[rng.random() for _ in range(8)] for _ in range(40)]))
        self.identity = d.finish()
        self.kw = kw

    def call(self, relate=None, **kw):
        u = LogUnit(self.a, self.src, 1000 * len(self.periods), f"{self.src[-6:]}.mcap",
                    self.gap, (), self.identity, Relations(relate or {}),
                    tuple(p.start_t for p in self.periods), **{**self.kw, **kw})  # fmt: skip
        return [u], list(self.periods), list(self.alarms)


def _history(rng: random.Random, n: int) -> list[_Log]:
    """``n`` logs of the two units in flight order: dated ones (a day apart), and for the
    second unit undated ones too; numbered by a flight record or by the gap rule."""
    out = []
    for k in range(n):
        a = rng.choice(UNITS)
        dated = a == UNITS[0] or rng.random() < 0.5  # the other unit's mixed
        gap = rng.random() < 0.6
        su = 1.7e9 + DAY * k + rng.uniform(0, 3600) if dated else None
        t0 = rng.choice((0.0, 1000.0 * k))
        m = rng.randint(1, 4)
        dts = [rng.choice((600.0, 900.0, 3000.0)) for _ in range(m)]
        ps, t = [], t0
        for dt in dts:
            ps.append(_period(a, t, min(dt, 500.0), rng, flight=0 if gap else k,
                              start_unix=None if su is None else su + (t - t0)))  # fmt: skip
            t += dt
        al = [AlarmEvent(a, ps[-1].start_t + 1.0, rng.choice(("leak", "supply")), 1.0, "replay")
              for _ in range(rng.randint(0, 1))]  # fmt: skip
        out.append(_Log(a, f"log:{rng.getrandbits(64):016x}", ps, al, gap, rng))
    return out


def _grown(log: _Log, rng: random.Random) -> _Log:
    """A longer version of ``log`` (its samples and one more period): it supersedes it."""
    last = log.periods[-1]
    extra = _period(log.a, last.end_t + 10.0, 400.0, rng, flight=last.flight,
                    start_unix=None if last.start_unix is None
                    else last.start_unix + (last.end_t + 10.0 - last.start_t))  # fmt: skip
    return _Log(log.a, f"log:{rng.getrandbits(64):016x}", [*log.periods, extra], log.alarms,
                log.gap, rng)  # fmt: skip


def _snapshot(url: str) -> dict:
    def clean(v):
        return "nan" if isinstance(v, float) and math.isnan(v) else v

    with open_store(url) as s:
        b = s._b
        out = {}
        for t, key in (("periods", "actuator, start_t, source"), ("alarms", "actuator, t, kind"),
                       ("log_sources", "actuator, source"), ("summary", "actuator")):  # fmt: skip
            cur = b.execute(f"SELECT * FROM {t} ORDER BY {key}")
            cols = [d[0] for d in cur.description]
            out[t] = [dict(zip(cols, map(clean, r), strict=True)) for r in cur.fetchall()]
        assert s.check() == []
    return out


def _diff(a: dict, b: dict) -> list:
    """Where two snapshots differ: (table, row, column, one, other)."""
    out = []
    for t in a:
        if len(a[t]) != len(b[t]):
            out.append((t, "rows", len(a[t]), len(b[t])))
            continue
        for i, (x, y) in enumerate(zip(a[t], b[t], strict=True)):
            out += [(t, i, k, x[k], y[k]) for k in x if x[k] != y[k]]
    return out


def _other(request, store_url, tmp_path) -> str:
    if store_url.startswith("postgresql"):
        return request.getfixturevalue("pg_cluster").create_database()
    return str(tmp_path / "full.sqlite")


@pytest.fixture
def appended(monkeypatch) -> list[bool]:
    """Whether each unit's write took the incremental path (``renumber_append``)."""
    seen: list[bool] = []
    real = ingest_mod.renumber_append

    def spy(*a, **kw):
        seen.append(real(*a, **kw))
        return seen[-1]

    monkeypatch.setattr(ingest_mod, "renumber_append", spy)
    return seen


@pytest.mark.parametrize("seed", [1, 2])
def test_incremental_equals_the_whole_renumbering_in_any_arrival(
    request, store_url, tmp_path, appended, seed
):
    rng = random.Random(seed)
    hist = _history(rng, 48)
    order = list(range(len(hist)))  # in flight order but for a few logs that come late
    for _ in range(5):
        i = rng.randrange(len(order) - 1)
        order.insert(min(len(order) - 1, i + rng.randint(1, 8)), order.pop(i))
    full = _other(request, store_url, tmp_path)
    sent: list[_Log] = []
    lives = 0
    with open_store(store_url) as inc, open_store(full) as ref:
        pos = 0
        while pos < len(order):
            batch, gap_s = [], rng.choice((1800.0,) * 12 + (900.0,))
            for _ in range(rng.randint(1, 4)):
                if pos >= len(order):
                    break
                r = rng.random()
                if sent and r < 0.08:  # a copy of a stored log: nothing stored
                    batch.append(rng.choice(sent).call())
                elif sent and r < 0.14:  # a grown version: it replaces the stored one
                    old = rng.choice(sent)
                    new = _grown(old, rng)
                    batch.append(new.call({old.src: Relation(holds=True)}))
                    sent.append(new)
                elif sent and r < 0.18:  # --flight given for a stored log
                    batch.append(rng.choice(sent).call(flight=rng.randint(0, 50)))
                else:
                    log = hist[order[pos]]
                    pos += 1
                    if log.periods[0].start_unix is not None and rng.random() < 0.15:
                        # the daemon's live periods first, then its log replaces them
                        lives += 1
                        live = [Period(**{**p.to_dict(), "source": f"live:st/0@L{lives}",
                                          "flight": rng.choice((None, 7))})
                                for p in log.periods]  # fmt: skip
                        for s in (inc, ref):
                            assert s.add_periods(live) == len(live)
                        batch.append(log.call(live=f"@L{lives}"))
                    else:
                        batch.append(log.call())
                    sent.append(log)
            got_i = inc.ingest_logs(batch, gap_s)
            got_r = ref.ingest_logs(batch, gap_s, incremental=False)
            assert got_i == got_r
            assert _diff(_snapshot(store_url), _snapshot(full)) == []
    # the incremental path did most of the work, and the rest fell back to the whole walk
    assert appended.count(True) >= 10 and appended.count(False) >= 5


def test_an_append_reads_no_history(store_url, monkeypatch, appended):
    rng = random.Random(5)
    hist = [log for log in _history(rng, 60)
            if log.a == UNITS[0] and log.periods[0].start_unix is not None]  # fmt: skip
    with open_store(store_url) as s:
        for log in hist[:-1]:
            s.ingest_logs([log.call()], 1800.0)
        with monkeypatch.context() as m:
            m.setattr(type(s), "periods", lambda *_: pytest.fail("read the unit's history"))
            m.setattr(type(s), "rules", lambda *_: pytest.fail("read the unit's rules"))
            s.ingest_logs([hist[-1].call()], 1800.0)
    assert appended[-1] is True


def test_migration_8_keeps_an_old_store_and_renumbers_it_whole_once(
    request, store_url, tmp_path, appended
):
    rng = random.Random(9)
    hist = [log for log in _history(rng, 40)
            if log.a == UNITS[0] and log.periods[0].start_unix is not None]  # fmt: skip
    full = _other(request, store_url, tmp_path)
    for url in (store_url, full):
        with open_store(url) as s:
            for log in hist[:4]:
                s.ingest_logs([log.call()], 1800.0, incremental=False)
    with open_store(store_url) as s, s._b.transaction():  # the store before migration 8
        b = s._b
        roll_back(b, 7)
        assert s.schema_version() == 7
    with open_store(store_url) as s:
        assert s.schema_version() == 8
        assert {r[0] for r in s._b.execute("SELECT renumber_from FROM summary")} == {"[]"}
    # the rows as they were, the summary rebuilt equal (but where its flights stand)
    assert _rows(store_url) == _rows(full)
    del appended[:]
    for log in hist[4:]:
        for url, inc in ((store_url, True), (full, False)):
            with open_store(url) as s:
                s.ingest_logs([log.call()], 1800.0, incremental=inc)
        assert _rows(store_url) == _rows(full)
    assert appended[0] is False and appended[-1] is True  # whole once, then appends
    assert _snapshot(store_url) == _snapshot(full)  # each unit written since: all equal


def _rows(url: str) -> dict:
    out = _snapshot(url)
    for r in out["summary"]:
        del r["renumber_from"], r["flight_gap_s"]
    return out
