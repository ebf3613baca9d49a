"""``servowatch rul``'s table keeps its columns apart (issue 54, on a fresh clone: a unit
whose history is too short read ``1.04insufficient history``)."""

from __future__ import annotations

from service.cli.dispatch import main
from service.store import open_store
from tests.test_store import make_period


def test_a_long_status_does_not_run_into_the_ratio(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    with open_store(db) as s:
        s.add_periods([make_period("AC001/elevator_L", 1, ratio=1.04)])
    assert main(["rul", "--store", str(db), "--no-save"]) == 0
    head, row = capsys.readouterr().out.splitlines()[1:3]
    assert row.split()[:4] == ["AC001/elevator_L", "1.04", "insufficient", "history"], row
    assert head.split()[:3] == ["actuator", "ratio", "model"] and len(row) <= 100, (head, row)
    assert head.index("model") == row.index("insufficient")  # the column starts where it says
