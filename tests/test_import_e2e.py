"""Issue 52 end to end, the user's path only: the HF bench's healthy run and a leak run (C_Lk 3 x
nominal) written as TDMS and as MDF4 under a rig's names and units, ``servowatch import``,
``servowatch calibrate --log`` (the unit commissioned on the healthy run),
``servowatch replay --store``; the stored period's leak ratio within 10 % of the truth."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
import rig_files as rf  # noqa: E402

from service.cli import main  # noqa: E402

RATIO = 3.0


@pytest.fixture(scope="module")
def runs():
    return rf.run("healthy", seconds=4.0), rf.run("leak", seconds=6.0, ratio=RATIO)


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["tdms", "mdf"])
def test_import_calibrate_replay_reads_the_leak(tmp_path, runs, fmt, capsys):
    from service.store import open_store

    healthy, leak = runs
    writer, ext, prefix = (rf.write_tdms, ".tdms", "Rig/") if fmt == "tdms" else (
        rf.write_mdf4, ".mf4", "")  # fmt: skip
    mp = tmp_path / "rig.toml"
    mp.write_text(rf.map_text(fmt, prefix))
    logs = tmp_path / "logs"
    files = [writer(tmp_path / f"{name}{ext}", meas) for name, meas in
             (("healthy", healthy), ("leak", leak))]  # fmt: skip
    assert main(["import", *map(str, files), "--map", str(mp), "--out", str(logs)]) == 0
    store = tmp_path / "health.sqlite"
    assert main(["calibrate", "--log", str(logs / "healthy.mcap"), "--store", str(store)]) == 0
    assert main(["replay", str(logs / "leak.mcap"), "--store", str(store)]) == 0
    with open_store(store) as st:
        (p,) = st.periods("RIG1/rudder")
        assert st.latest_baseline("RIG1/rudder") is not None
    assert p.start_unix == rf.START.timestamp()  # dated by the file's own start time
    assert abs(p.c_lk_ratio / RATIO - 1) < 0.10, p.c_lk_ratio
    # a second import of the same files writes nothing
    before = (logs / "leak.mcap").read_bytes()
    assert main(["import", *map(str, files), "--map", str(mp), "--out", str(logs)]) == 0
    assert (logs / "leak.mcap").read_bytes() == before
