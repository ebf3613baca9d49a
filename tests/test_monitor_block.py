"""The block path of ``MonitorBank`` (``update_rows``/``update_many``: vectorised parsing, one
compiled loop over the block) against the per-round reference path, bit for bit, on a
randomised multi-actuator stream with bad samples, gaps and re-initialisations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from service.monitor import AlarmConfig, Monitor, MonitorBank, MonitorConfig
from service.monitor.calibration import measured_run
from service.sim.scenarios import load_scenario

KEYS = ("t", "x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr")
_MEAS: dict = {}


def _meas():
    if not _MEAS:
        sc = load_scenario("healthy_noise").model_copy(update={"duration_s": 0.8})
        _MEAS.update(measured_run(sc, with_supply_sensor=True)[1])
    return _MEAS


def _stream(seed: int) -> list[tuple[str, dict]]:
    """Three actuators interleaved in random chunks, with every kind of bad sample."""
    meas = _meas()
    rng = np.random.default_rng(seed)
    cols = [np.asarray(meas[k], float).tolist() for k in KEYS]
    base = [dict(zip(KEYS, row, strict=True)) for row in zip(*cols, strict=True)]
    per: dict[str, list[dict]] = {}
    for a, name in enumerate(("A", "B", "C")):
        rows = []
        for j, s0 in enumerate(base):
            s = dict(s0)
            s["t"] = s0["t"] + 0.25 * a
            if name == "B" and 300 <= j < 380:
                continue  # an 80 ms hole: gap, re-init
            u = rng.random()
            if u < 0.02:
                s[rng.choice(KEYS[1:])] = math.nan
            elif u < 0.03:
                s[rng.choice(KEYS[1:])] = math.inf
            elif u < 0.05:
                s[rng.choice(KEYS[1:])] = None  # missing channel
            elif u < 0.055:
                s["p1"] = "not a number"
            elif u < 0.06:
                s["p2"] = int(round(s["p2"]))
            elif u < 0.065:
                s["t"] = math.nan if rng.random() < 0.5 else None
            elif u < 0.07:
                s = {"t": s["t"], "x_s": None, "i": math.nan}  # nothing usable
            rows.append(s)
            if rng.random() < 0.01:
                rows.append(dict(s))  # duplicate time
            if rng.random() < 0.01 and j > 2:
                rows.append(dict(base[j - 2], t=base[j - 2]["t"] + 0.25 * a))  # out of order
        per[name] = rows
    per["C"][500] = dict(per["C"][500], x_j=0.5)  # far off: the NIS average diverges
    per["C"][650] = dict(per["C"][650], x_s=1e300, p1=1e300)  # breaks the filter
    out: list[tuple[str, dict]] = []
    pos = dict.fromkeys(per, 0)
    while any(pos[n] < len(per[n]) for n in per):
        for n in rng.permutation(list(per)):
            take = int(rng.integers(0, 60))
            out.extend((n, s) for s in per[n][pos[n] : pos[n] + take])
            pos[n] += take
    return out


def _cfg() -> MonitorConfig:
    # low thresholds so that the alarms raise (and the supply one clears) in a short run
    return MonitorConfig(
        arm_s=0.05,
        alarms=AlarmConfig(
            leak_raise=0.9, leak_clear=0.5, supply_raise=1.5, supply_clear=1.6, hold_s=0.01,
            leak_max_sigma=100.0, supply_max_sigma=10.0,
        ),
    )  # fmt: skip


def _batches(n: int, rng) -> list[tuple[int, int]]:
    cuts = np.unique(np.concatenate([[0, n], rng.integers(0, n, size=max(1, n // 150))]))
    return list(zip(cuts[:-1].tolist(), cuts[1:].tolist(), strict=True))


def _bits(a) -> bytes:
    return np.ascontiguousarray(a, float).tobytes()


@pytest.fixture(scope="module")
def stream():
    return _stream(7)


def _state(bank: MonitorBank):
    return [_bits(getattr(bank, a)) for a in ("x", "P", "ol", "t_last", "carry", "nis_avg")]


def test_block_rows_equal_round_rows(stream):
    rng = np.random.default_rng(1)
    ref, new = MonitorBank(_cfg()), MonitorBank(_cfg())
    for a, b in _batches(len(stream), rng):
        r0 = ref.update_rows_rounds(stream[a:b])
        r1 = new.update_rows(stream[a:b])
        assert r0.index.tolist() == r1.index.tolist()
        assert _bits(r0.t) == _bits(r1.t)
        assert _bits(r0.est) == _bits(r1.est)
        assert _bits(r0.res) == _bits(r1.res)
        assert _bits(r0.health) == _bits(r1.health)
        assert r0.events == r1.events
    for key in ("A", "B", "C"):
        assert ref.counters_of(key) == new.counters_of(key)
    assert ref.events_log == new.events_log
    assert _state(ref) == _state(new)
    assert _bits(ref.pending) == _bits(new.pending) and (ref.alarm == new.alarm).all()
    # the stream exercised every path
    c = {k: sum(new.counters_of(n)[k] for n in "ABC") for k in new.counters_of("A")}
    assert c["gap"] >= 1 and c["reinit"] >= 2 and c["skipped_time"] >= 3
    assert c["skipped_nan"] >= 3 and c["bad_channel"] >= 10 and c["missing_channel"] >= 10
    kinds = {(e.kind, e.state) for evs in new.events_log for e in evs}
    assert {("reinit", "raised"), ("leak", "raised"), ("supply", "raised")} <= kinds


def test_block_many_equals_rounds_and_monitor(stream):
    """update_many (block) with other batch cuts = per-round reference = Monitor one by one."""
    rng = np.random.default_rng(2)
    ref, new = MonitorBank(_cfg()), MonitorBank(_cfg())
    out0, out1 = [], []
    for a, b in _batches(len(stream), rng):
        out0 += ref.update_many_rounds(stream[a:b])
    for a, b in _batches(len(stream), rng):
        out1 += new.update_many(stream[a:b])
    assert out0 == out1
    mons = {n: Monitor(_cfg()) for n in "ABC"}
    out2 = [mons[n].update(s) for n, s in stream[:1500]]
    for n in "ABC":
        mine = [o for (k, _), o in zip(stream[:1500], out2, strict=True) if k == n]
        theirs = [o for (k, _), o in zip(stream[:1500], out0[:1500], strict=True) if k == n]
        assert mine == theirs
    for n in "ABC":
        assert ref.counters_of(n) == new.counters_of(n)


def test_block_reduced_channels(stream):
    cfg = _cfg().model_copy(update={"channels": "reduced"})
    ref, new = MonitorBank(cfg), MonitorBank(cfg)
    r0 = ref.update_rows_rounds(stream[:3000])
    r1 = new.update_rows(stream[:3000])
    assert r0.index.tolist() == r1.index.tolist()
    assert _bits(r0.est) == _bits(r1.est) and _bits(r0.res) == _bits(r1.res)
    assert _bits(r0.health) == _bits(r1.health) and r0.events == r1.events
    for n in "ABC":
        assert ref.counters_of(n) == new.counters_of(n)


def test_empty_block():
    bank = MonitorBank()
    r = bank.update_rows([])
    assert r.est.shape == (0, 18) and r.events == []
    assert bank.update_many([("A", {"t": 0.0})]) == [None]
    assert bank.counters_of("A")["skipped_nan"] == 1


def _as_arrays(bank: MonitorBank, part):
    """(ks, t, channels) of ``update_arrays`` for dict samples (None, NaN, text -> NaN)."""
    from service.wire.messages import CHANNELS

    def num(v):
        return v if isinstance(v, int | float) and not isinstance(v, bool) else math.nan

    ks = np.array([bank.index_of(k) for k, _ in part], np.int64)
    t = np.array([num(s.get("t")) for _, s in part], float)
    ch = np.array([[num(s.get(c)) for c in CHANNELS] for _, s in part], float).reshape(-1, 7)
    return ks, t, ch


def test_update_arrays_equals_update_rows(stream):
    """The array entry point (the daemon's and the replay's) gives the dict path's bits when
    NaN stands for an absent value (None); inf stays a bad value in both."""

    def absent(v):
        bad = v is None or isinstance(v, str) or (isinstance(v, float) and math.isnan(v))
        return None if bad else v

    dicts = [(k, {c: absent(v) for c, v in s.items()}) for k, s in stream]
    rng = np.random.default_rng(3)
    ref, new = MonitorBank(_cfg()), MonitorBank(_cfg())
    for a, b in _batches(len(dicts), rng):
        part = dicts[a:b]
        r0 = ref.update_rows(part) if b - a > 2 else ref._run_block(part)
        r1 = new.update_arrays(*_as_arrays(new, part))
        assert r0.index.tolist() == r1.index.tolist()
        assert _bits(r0.t) == _bits(r1.t) and _bits(r0.est) == _bits(r1.est)
        assert _bits(r0.res) == _bits(r1.res) and _bits(r0.health) == _bits(r1.health)
        assert r0.events == r1.events
    for key in ("A", "B", "C"):
        assert ref.counters_of(key) == new.counters_of(key)
    assert _state(ref) == _state(new)
    with pytest.raises(ValueError, match="index_of"):
        new.update_arrays(np.array([7]), np.array([1.0]), np.zeros((1, 7)))
    with pytest.raises(ValueError, match="channels"):
        new.update_arrays(np.array([0]), np.array([1.0]), np.zeros((1, 6)))


def test_step_arrays_then_rows_of_pipelined(stream):
    """The replay's pipeline: ``step_arrays`` of later blocks run in a worker thread before
    ``rows_of`` of earlier ones (in order) gives ``update_arrays``'s bits: rows, alarm and
    re-initialisation events, counters and state."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(11)
    ref, new = MonitorBank(_cfg()), MonitorBank(_cfg())
    for key in ("A", "B", "C"):  # all actuators known first: index_of must not grow mid-run
        ref.index_of(key), new.index_of(key)
    parts = [stream[a:b] for a, b in _batches(len(stream), rng)]
    want = [ref.update_arrays(*_as_arrays(ref, p)) for p in parts]
    with ThreadPoolExecutor(1) as pool:
        futs = [pool.submit(new.step_arrays, *_as_arrays(new, p)) for p in parts]
        got = []
        for f in futs:
            sb = f.result()
            got.append(new.rows_of(sb) if sb is not None else None)
    n_events = 0
    for r0, r1 in zip(want, got, strict=True):
        if r1 is None:
            assert len(r0.index) == 0
            continue
        assert r0.index.tolist() == r1.index.tolist()
        assert _bits(r0.est) == _bits(r1.est) and _bits(r0.res) == _bits(r1.res)
        assert _bits(r0.health) == _bits(r1.health) and r0.events == r1.events
        n_events += sum(len(e) for e in r1.events)
    kinds = {e.kind for r in got if r is not None for ev in r.events for e in ev}
    assert {"leak", "reinit"} <= kinds and n_events >= 3  # the stream exercises both paths
    for key in ("A", "B", "C"):
        assert ref.counters_of(key) == new.counters_of(key)
    assert _state(ref) == _state(new)
    assert _bits(ref.alarm) == _bits(new.alarm)


def test_row_events_sequence():
    """``RowEvents``: a list per row, [] where a row has none, equal to the plain lists."""
    from service.monitor import AlarmEvent, RowEvents

    e = AlarmEvent(1.0, "leak", "raised", 1.2)
    ev = RowEvents(4, {2: [e]})
    assert len(ev) == 4 and ev[0] == [] and ev[2] == [e] and ev[-2] == [e]
    assert ev == [[], [], [e], []] and ev == RowEvents.of([[], [], [e], []])
    assert ev.flags().tolist() == [False, False, True, False] and ev.rows() == [2]
    assert ev[1:3] == [[], [e]]
    with pytest.raises(IndexError):
        ev[4]
    ev[0].append(e)  # a fresh list: other rows are not touched
    assert ev[0] == [] and ev[1] == []
