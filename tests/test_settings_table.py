"""docs/estimation.md's table of settings is the one the code generates, and it lists every
setting the monitor reads: each row's default builds a working bank."""

from __future__ import annotations

from pathlib import Path

from service.monitor import MonitorBank, MonitorConfig
from service.monitor.settings_table import BEGIN, END, replace_table, settings_rows, settings_table

DOC = Path(__file__).resolve().parent.parent / "docs" / "estimation.md"


def test_docs_table_is_the_generated_one():
    text = DOC.read_text()
    block = text[text.index(BEGIN) + len(BEGIN) : text.index(END)]
    assert block == "\n" + settings_table(), (
        "docs/estimation.md's settings table is stale: python -m service.monitor.settings_table "
        "--write"
    )


def test_every_setting_is_listed_once_with_a_concrete_value():
    names = [n.strip("`") for n, _, _ in settings_rows()]
    assert len(names) == len(set(names)) > 50
    cfg = MonitorConfig()
    for n in names:  # every row names a real setting, with a value (no None resolved later)
        obj = cfg
        for part in n.split("."):
            obj = getattr(obj, part)
        assert obj is not None, n
    assert "process.p_sr" in names and "alarms.leak_max_sigma" in names


def test_a_changed_setting_changes_the_table_and_the_bank():
    table = settings_table()
    assert replace_table(f"a\n{BEGIN}\nold\n{END}\nb", table) == f"a\n{BEGIN}\n{table}{END}\nb"
    base, loud = MonitorBank(MonitorConfig()), MonitorBank(MonitorConfig(process={"c_lk": 2e-13}))
    assert loud._q[6] > base._q[6]
