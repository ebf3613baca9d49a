"""Time plausibility in the daemon's intake (service.daemon.intake)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from service.config import ServiceConfig
from service.daemon import RateLimitedLog
from service.daemon.intake import ActuatorState, ClockCheck, accept
from service.wire import messages as m
from tests.test_daemon import KEY, make, sample

T0 = 1.7e9  # a Unix-time sample clock


def arrays(seqs, ts) -> m.MeasArrays:
    return m.MeasArrays(np.asarray(seqs, np.int64), np.asarray(ts, float), np.zeros((len(ts), 7)))


def feed(st, msgs, now=None, ck=None):
    restarts = []
    out = []
    for seqs, ts in msgs:
        r = accept(
            st, arrays(seqs, ts), RateLimitedLog(logging.getLogger("t"), 60),
            lambda s, t, q, back: restarts.append((t, q, back)), ck, now,
        )  # fmt: skip
        out.append(r)
    return out, restarts


def good(k0, n=10, t0=T0, p=1e-3):
    return list(range(k0, k0 + n)), [t0 + k * p for k in range(k0, k0 + n)]


def test_one_sample_far_ahead_costs_that_sample_only():
    st = ActuatorState("AC001", "ail")
    out, rs = feed(st, [good(0), ([10], [T0 + 1e6]), good(11), good(21)])
    assert out == [(0, 10), (0, 0), (0, 10), (0, 10)]
    assert st.bad == {"clock": 1} and st.samples == 30 and rs == [] and st.gaps == 0


def test_last_sample_of_a_message_ahead_is_cut_off_alone():
    st = ActuatorState("AC001", "ail")
    s, t = good(10)
    t[-1] += 50.0
    out, _ = feed(st, [good(0), (s, t), good(20)])
    assert out == [(0, 10), (0, 9), (0, 10)]
    assert st.bad == {"clock": 1} and st.samples == 29


def test_ahead_of_the_receiving_clock_is_refused_even_first():
    st = ActuatorState("AC001", "ail")
    now = T0 + 1.0
    out, _ = feed(st, [([0], [now + 100.0]), good(1)], now=now)
    assert out == [(0, 0), (0, 10)]
    assert st.bad == {"clock": 1} and st.last_seq == 10
    # never re-synchronised on, however many come
    out, rs = feed(st, [good(k, t0=T0 + 1e3) for k in (11, 21, 31)], now=now)
    assert [o[1] - o[0] for o in out] == [0, 0, 0] and rs == [] and st.bad["clock"] == 31


def test_forward_clock_step_is_followed_after_k_samples():
    st = ActuatorState("AC001", "ail")
    ck = ClockCheck(resync_n=5)
    msgs = [good(0)] + [([k], [T0 + 100.0 + k * 1e-3]) for k in range(10, 20)]
    out, rs = feed(st, msgs, ck=ck)
    assert [o[1] - o[0] for o in out] == [10] + [0] * 5 + [1] * 5
    assert st.restarts == 1 and rs[0][2] is False and st.bad == {"clock": 5}
    assert st.last_t == pytest.approx(T0 + 100.019)


def test_reboot_at_1970_is_followed_and_late_samples_are_not():
    st = ActuatorState("AC001", "ail")
    out, rs = feed(st, [good(0), good(10), good(5, n=3), good(0, n=10, t0=0.0), good(10, t0=0.0)])
    assert st.bad == {"out_of_order": 3, "clock": 5}  # seq 5-7 late; 5 samples to resync
    assert out[3] == (5, 10) and out[4] == (0, 10)
    assert st.restarts == 1 and rs == [(pytest.approx(0.004), 4, True)]
    assert st.last_t == pytest.approx(0.019)


def test_clock_check_validates_its_fields():
    with pytest.raises(ValueError, match="clock.factor"):
        ClockCheck(factor=0.5)
    with pytest.raises(ValueError, match="clock.resync_n"):
        ClockCheck(resync_n=0)
    with pytest.raises(ValueError, match="clock"):
        ServiceConfig.model_validate({"clock": {"tol_s": -1}})


def test_daemon_counts_bad_clock_and_logs_every_good_sample():
    d, lg, bank = make()
    for k in range(0, 100, 10):
        d.submit(KEY, m.encode_meas([sample(j) for j in range(k, k + 10)]))
        if k == 50:
            d.submit(KEY, m.encode_meas([sample(10_000, t=1000.0 + 1e6)]))
    d.process_pending()
    a = d.status()["actuators"][KEY]
    assert a["bad"] == {"clock": 1} and a["samples"] == 100 and a["missed"] == 0
    assert len(lg.topic("/meas")) == 100 and len(bank.seen(KEY)) == 100
