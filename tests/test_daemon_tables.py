"""The daemon's per-unit state is bounded per source (issue 43, items 3 and 5): one aircraft
(one acquisition identity) cannot fill the unit table for the others, silent units leave it,
every refusal is counted and reported, and a key that breaks the key grammar never enters
and cannot forge a plain log line."""

from __future__ import annotations

import io
import logging

from test_daemon import make, sample

from service.wire import messages as m

REAL = "fleet/AC002/rudder/meas"


def _junk(d, n: int, t_recv: float | None = None) -> list[bool]:
    """An AC001 certificate's junk keys: whether each was let in."""
    return [
        d.submit(f"fleet/AC001/junk{i}/meas", m.encode_meas([sample(0)]), t_recv) for i in range(n)
    ]


def test_one_aircraft_cannot_fill_the_unit_table_for_the_others():
    d, _, _ = make()
    admitted = _junk(d, 1000)  # an AC001 certificate's junk keys, as many as the whole table
    d.process_pending()
    assert sum(admitted) == 64  # its aircraft's cap
    d.submit(REAL, m.encode_meas([sample(0), sample(1)]))  # another aircraft's real unit
    d.process_pending()
    st = d.status()
    assert st["actuators"][REAL]["samples"] == 2
    assert st["unknown"] == {"aircraft_full": 1000 - 64}
    table = st["unit_table"]
    assert table["refused"] == {"AC001": 1000 - 64}
    assert table["per_aircraft"] == {"AC001": 64, "AC002": 1}
    assert table["units"] == 65 and table["max_per_aircraft"] == 64


def test_silent_units_leave_the_table_and_free_their_slots():
    d, _, _ = make(max_units_per_aircraft=4, unit_expire_s=60.0)
    assert sum(_junk(d, 10, t_recv=100.0)) == 4
    d.process_pending()
    key = "fleet/AC001/elevator_L/meas"
    assert not d.submit(key, m.encode_meas([sample(0)]), 120.0)  # AC001 is full
    assert d.expire_units(now=150.0) == []  # silent 50 s < 60 s: still there
    gone = d.expire_units(now=170.0)
    assert sorted(gone) == sorted(f"AC001/junk{i}" for i in range(4))
    assert d.submit(key, m.encode_meas([sample(0), sample(1)]), 171.0)
    d.process_pending()
    st = d.status()
    assert list(st["actuators"]) == [key] and st["actuators"][key]["samples"] == 2
    assert st["unit_table"]["expired"] == 4 and st["unit_table"]["per_aircraft"] == {"AC001": 1}


def test_a_key_with_a_newline_is_refused_and_cannot_forge_a_plain_log_line():
    from service.cli.commands.run import setup_logging

    setup_logging("INFO", structured=False)  # --plain-logs
    buf = io.StringIO()
    root = logging.getLogger()
    root.handlers[0].stream = buf
    try:
        d, _, _ = make()
        forged = "2026-12-03 12:00:00,000 ERROR servowatch.daemon FORGED"
        key = f"fleet/AC001/x\n{forged}/meas"
        assert not d.submit(key, m.encode_meas([sample(0)]))
        d.process_pending()
        assert d.status()["unknown"] == {"invalid_key": 1}
        logging.getLogger("servowatch.daemon").warning("quoted: %s", "a\nb\r\x1b[2Jc\u2028d")
    finally:
        root.handlers[0].stream = __import__("sys").stderr
    lines = buf.getvalue().splitlines()
    assert not any(ln.startswith(forged[:10]) and "FORGED" in ln and "invalid_key" not in ln
                   for ln in lines), lines  # fmt: skip
    assert any("invalid_key" in ln and "FORGED" in ln for ln in lines), lines
    (q,) = [ln for ln in lines if "quoted:" in ln]
    assert q.endswith("quoted: a\\nb\\r\\x1b[2Jc\\u2028d"), q
