"""A monitor's re-initialisation line says when in calendar time, never as an epoch float
(issue 54: ``t=1796378000.5361416``), with its unit, time and NIS average as fields."""

from __future__ import annotations

import logging

import numpy as np
from loglines import is_time
from test_monitor_zeros import N_PRE, _feed, healthy  # noqa: F401 (the fixture)

from service.monitor import MonitorBank, MonitorConfig
from service.wire.messages import CHANNELS

T0 = 1796378000.0  # 2026-12-04T09:53:20Z


def test_a_reinit_at_a_calendar_time_logs_rfc3339(healthy, caplog):  # noqa: F811
    t_h, ch_h = healthy
    bank = MonitorBank(MonitorConfig(model="C5"))
    t = T0 + t_h[:N_PRE]
    _feed(bank, "AC001/x", t, ch_h[:N_PRE])
    with caplog.at_level(logging.WARNING, logger="service.monitor.bank"):
        t_z = t[-1] + 1e-3 * np.arange(1, 51)
        _feed(bank, "AC001/x", t_z, np.zeros((50, len(CHANNELS))))
    (rec,) = [r for r in caplog.records if "re-initialised" in r.getMessage()]
    msg = rec.getMessage()
    assert msg.startswith("monitor AC001/x re-initialised at 2026-12-04T09:53:21."), msg
    assert "t=" not in msg and "1796378" not in msg, msg
    f = rec.fields
    assert f["event"] == "reinit" and f["unit"] == "AC001/x" and is_time(f["event_time"]), f
