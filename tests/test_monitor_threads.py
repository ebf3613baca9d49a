"""A block stepped in two threads (``MonitorConfig.threads = 2``: the actuators split between
the caller's thread and one more) gives the numbers, events and counters of one thread,
through gaps, re-initialisations and bad samples."""

from __future__ import annotations

import numpy as np

from service.monitor import MonitorBank, MonitorConfig
from service.monitor.calibration import measured_run
from service.sim.scenarios import load_scenario
from service.wire.messages import CHANNELS


def _stream(n_act: int = 5):
    sc = load_scenario("leak_step").model_copy(update={"duration_s": 0.6})
    _, meas = measured_run(sc, with_supply_sensor=True)
    t = np.asarray(meas["t"], float)
    ch = np.column_stack([np.asarray(meas[c], float) for c in CHANNELS])
    ks, ts, chs = [], [], []
    for a in range(n_act):
        keep = (t < 0.2) | (t >= 0.3) if a == 1 else np.ones(len(t), bool)  # a gap: re-init
        c = ch[keep].copy()
        if a == 2:
            c[::9, CHANNELS.index("p1")] = np.nan  # missing channels
            c[5::13, CHANNELS.index("i")] = np.inf  # bad values
        if a == 3:
            c[400:, CHANNELS.index("p2")] = 0.0  # a dead transducer: re-initialises
        ks.append(np.full(keep.sum(), a))
        ts.append(t[keep])
        chs.append(c)
    pos = np.concatenate([np.arange(len(x)) for x in ts])
    order = np.lexsort((np.concatenate(ks), pos))
    return np.concatenate(ks)[order], np.concatenate(ts)[order], np.concatenate(chs)[order]


def _run(threads: int):
    ks, t, ch = _stream()
    bank = MonitorBank(MonitorConfig(threads=threads))
    rows_k = [bank.index_of(f"act{a}") for a in range(5)]
    out = []
    for a in range(0, len(ks), 300):
        r = bank.update_arrays(np.array(rows_k)[ks[a : a + 300]], t[a : a + 300], ch[a : a + 300])
        out.append((r.index, r.t, r.est, r.res, r.health,
                    [(j, e) for j in r.events.rows() for e in r.events[j]]))  # fmt: skip
    return out, [bank.counters_of(f"act{a}") for a in range(5)]


def test_two_threads_give_the_numbers_of_one():
    one, c1 = _run(1)
    two, c2 = _run(2)
    assert c1 == c2
    assert c1[1]["gap"] == 1 and c1[2]["bad_channel"] > 0
    assert sum(c["reinit"] for c in c1) >= 1
    for a, b in zip(one, two, strict=True):
        for x, y in zip(a[:5], b[:5], strict=True):
            np.testing.assert_array_equal(x, y)
        assert a[5] == b[5]
