"""Counts read as words (issue 54: "1 periods", "RUL 1 flights"): every count a person reads
goes through ``service.cli.util.plural`` (or says its noun by the count in service.log)."""

from __future__ import annotations

from pathlib import Path

from service.cli.util import plural


def test_plural():
    assert plural(1, "period") == "1 period" and plural(3, "period") == "3 periods"
    assert plural(0, "flight") == "0 flights" and plural(1.0, "flight") == "1 flight"
    assert plural(1.5, "flight") == "1.5 flights" and plural(20.0, "flight") == "20 flights"
    assert plural(15_000_000, "sample") == "15000000 samples"
    assert plural(None, "unit") == "- units" and plural(True, "unit") == "- units"
    assert plural(float("nan"), "unit") == "- units"
    assert (
        plural(1, "child", "children") == "1 child"
        and plural(2, "child", "children") == "2 children"
    )


def test_listens_closing_line():
    from service.cli.commands.listen import summary_text

    assert summary_text({"received": 1, "malformed": 0}) == "listen: 1 output, 0 malformed"
    assert summary_text({"received": 6, "malformed": 1}) == "listen: 6 outputs, 1 malformed"


def test_a_truncated_log_with_one_chunk():
    from service.log.reader import LogReadStats, truncation_text

    st = LogReadStats()
    st.chunks, st.messages, st.reason, st.truncated = 1, 1, "no footer", True
    text = truncation_text(Path("a.mcap"), st)
    assert text == "a.mcap: truncated MCAP log (no footer); read 1 complete chunk, 1 message"


def test_rul_horizon_of_one_flight(tmp_path, capsys):
    from service.cli.dispatch import main
    from service.store import open_store

    db = tmp_path / "h.sqlite"
    with open_store(db) as s:
        s.ensure_actuator("AC001/elevator_L")
    assert main(["rul", "--store", str(db), "--no-save", "--horizon-flights", "1"]) == 0
    out = capsys.readouterr().out
    assert "horizon 1 flight (histories" in out and "1 flights" not in out, out


def test_status_group_line_of_one_takeover():
    from service.cli.commands.status import format_status

    st = {"station": "s", "shard": 0, "group": {"name": "fleet", "members": ["a"], "joined": True,
          "takeovers": 1, "released": 0, "held_units": 1}}  # fmt: skip
    text = format_status({"monitor/s/0/status": st})
    assert "1 unit taken over" in text, text
