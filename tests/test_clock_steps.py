"""A unit's clock that steps back (the daemon's intake rule, docs/messages.md "Measurement
sample schema"; the replay's time checks in docs/store.md "Migration 7"):
the samples at or before the last accepted time are refused and counted, and after
``resync_n`` (5) consistent refused samples the clock is followed (a restart, the filter
restarts there). The counts are those of the samples one by one, whatever the batches: a
message, a log's block, an imported file's block. Checked on a log without ``seq`` (replay:
summary, ``--json``, the summary line, the store) and through the importer (a Parquet
recording without ``seq``: its counts, its log, the log's replay), and on the daemon's intake
(its status counters). The truth is computed by hand from ``m``, the samples after the step
at times already passed."""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import rig_files as rf  # noqa: E402

from service.cli import main  # noqa: E402
from service.log import McapLogger, read_blocks  # noqa: E402
from service.replay import replay  # noqa: E402
from service.store import open_store  # noqa: E402

T0 = 1.75e9  # Unix sample times
RESYNC_N = 5  # ClockCheck.resync_n
STEP_AT = 1610  # mid-block (the logs below are written 250 samples a block)
UNIT = "AC1/ail_L"


@pytest.fixture(scope="module")
def meas():
    """3 s of the healthy HF bench with the scenario's sensor noise, 1 kHz."""
    return rf.run("healthy", seconds=3.0)


def _times(n: int, m: int, at: int = STEP_AT) -> np.ndarray:
    """1 kHz sample times whose clock steps back at sample ``at`` so that exactly ``m``
    samples after the step are at or before the last time before it (the m-th equal to it:
    the same float expression)."""
    k = np.r_[np.arange(at), np.arange(at - m, at - m + (n - at))]
    return T0 + k / 1000.0


def _truth(n: int, m: int) -> dict[str, int]:
    """The daemon's rule sample by sample: min(m, 5) refused (``clock``); at the 5th the clock
    is followed (a restart) and the rest are after the followed time."""
    refused = min(m, RESYNC_N)
    return {"accepted": n - refused, "clock": refused, "restarts": int(m >= RESYNC_N)}


def _log(path: Path, meas, t: np.ndarray) -> Path:
    """An acquisition-style log without ``seq``: the samples 250 at a time, several chunks."""
    chans = [k for k in meas if k != "t"]
    vals = np.column_stack([t] + [meas[c] for c in chans])
    with McapLogger(path, chunk_size=16_384, background_flush=False) as lg:
        for a in range(0, len(t), 250):
            lg.log_block(f"/fleet/{UNIT}/meas", t[a : a + 250], ("t", *chans), vals[a : a + 250])
    return path


# ----------------------------------------------------------------------- the rule itself


@pytest.mark.parametrize("m", [3, 5, 12, 40])
@pytest.mark.parametrize("size", [1, 7, 50, 400])
def test_accept_counts_a_step_back_the_same_in_any_batches(m, size):
    """``intake.accept`` on the same samples in messages of ``size``: the counts of the
    samples one by one (before: a message holding the 5th refused sample and a later one
    accepted the later ones, dropped those between uncounted and counted no restart)."""
    from service.daemon.intake import ActuatorState, ClockCheck, accept
    from service.daemon.ratelimit import RateLimitedLog
    from service.wire import messages as msg

    n, at = 300, 150
    t = _times(n, m, at)
    seq = np.arange(n)
    st = ActuatorState("AC1", "ail_L")
    bad = RateLimitedLog(logging.getLogger("test"))
    backs: list[bool] = []
    accepted = 0
    for a in range(0, n, size):
        tt, ss = t[a : a + size], seq[a : a + size]
        cut = np.flatnonzero(np.diff(tt) <= 0) + 1  # a message's samples increase
        for x, y in zip(np.r_[0, cut], np.r_[cut, len(tt)], strict=True):
            arr = msg.MeasArrays(ss[x:y], tt[x:y], np.zeros((y - x, len(msg.CHANNELS))))
            j0, j1 = accept(st, arr, bad, lambda *a: backs.append(a[3]), ClockCheck(), None)
            accepted += j1 - j0
    want = _truth(n, m)
    assert accepted == want["accepted"]
    assert st.bad == {"clock": want["clock"]}
    assert st.restarts == want["restarts"]
    # the filter restarts when the followed time is before the last one (the m-th sample
    # is at it: m = 5 follows a clock that did not go back past the last accepted time)
    assert backs == [m > RESYNC_N] * want["restarts"]


@pytest.mark.parametrize("size", [1, 2, 7, 50, 350])
def test_a_clock_that_jumps_forward_at_a_message_is_followed_after_5(size):
    """The stream's period known (a first message of 100 samples), the clock jumps 10 s
    forward at the first sample of a message of ``size``: 5 refused (``clock``), followed at
    the 5th, the rest accepted, whatever the message length (before: every sample of that
    message was refused, and the clock followed at its last)."""
    from service.daemon.intake import ActuatorState, ClockCheck, accept
    from service.daemon.ratelimit import RateLimitedLog
    from service.wire import messages as msg

    n, at = 900, 450
    t = T0 + np.arange(n) / 1000.0
    t[at:] += 10.0
    seq = np.arange(n)
    st = ActuatorState("AC1", "ail_L")
    bad = RateLimitedLog(logging.getLogger("test"))
    backs: list[bool] = []
    accepted = 0
    for a, b in [(0, 100)] + [(x, min(x + size, n)) for x in range(100, n, size)]:
        arr = msg.MeasArrays(seq[a:b], t[a:b], np.zeros((b - a, len(msg.CHANNELS))))
        j0, j1 = accept(st, arr, bad, lambda *x: backs.append(x[3]), ClockCheck(), None)
        accepted += j1 - j0
    assert (accepted, st.bad, st.restarts, backs) == (n - 5, {"clock": 5}, 1, [False])


def test_the_daemon_status_counts_a_step_back_into_a_message():
    """The daemon's intake (``Intake.take``, its status counters): a message of 60 samples,
    then one of 30 whose clock stepped back 20 samples (a message's own samples increase)."""
    from service.daemon import RateLimitedLog
    from service.daemon.intake import ClockCheck, Intake
    from service.wire import messages as msg

    it = Intake(queue_size=100, max_bytes=65536, clock=ClockCheck(), max_batch=10,
                bad_log=RateLimitedLog(logging.getLogger("test"), 60))  # fmt: skip
    key = f"fleet/{UNIT}/meas"
    t0 = _times(90, 20, 60)
    first = msg.encode_meas([{"seq": s, "t": float(t0[s]), "x_j": 0.0} for s in range(60)])
    rest = msg.encode_meas([{"seq": s, "t": float(t0[s]), "x_j": 0.0} for s in range(60, 90)])
    assert it.submit(key, first) and it.submit(key, rest)
    blocks = []
    while (b := it.take()) is not None:
        blocks.append(b)
    st = it.actuators[key]
    snap = st.snapshot(0.0)
    want = _truth(90, 20)
    assert snap["samples"] == want["accepted"] == 85
    assert snap["bad"] == {"clock": 5} and snap["restarts"] == 1
    assert sum(b.restarts.count(key) for b in blocks) == 1  # the filter restarts


# --------------------------------------------------------------- replay of a log without seq


@pytest.mark.parametrize("m", [2, 5, 12, 120, 700])
def test_replay_of_a_log_without_seq_counts_a_step_back(tmp_path, meas, m, capsys):
    """Every view of one replay (summary, ``--json``, the summary line) against the truth."""
    n = len(meas["t"])
    log = _log(tmp_path / "step.mcap", meas, _times(n, m))
    want = _truth(n, m)
    s = replay(log)
    tc = s.time[UNIT]
    assert s.samples == want["accepted"] and s.skipped == n - want["accepted"]
    assert (tc["clock"], tc["restarts"]) == (want["clock"], want["restarts"])
    assert tc["duplicate"] == tc["out_of_order"] == tc["non_finite"] == 0
    capsys.readouterr()
    assert main(["replay", str(log), "--json"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert js["samples"] == want["accepted"] and js["skipped"] == n - want["accepted"]
    assert js["time"][UNIT] == tc
    assert main(["replay", str(log)]) == 0
    text = capsys.readouterr().out
    line = [x for x in text.splitlines() if x.startswith("  time checks")]
    assert line == [f"  time checks {UNIT}: non_finite 0, duplicate 0, out_of_order 0, "
                    f"clock {want['clock']}, restarts {want['restarts']}"]  # fmt: skip
    assert f"{UNIT}: {want['clock']} samples refused by the time checks (clock " in text


@pytest.mark.parametrize("m", [12, 700])
def test_the_store_holds_the_accepted_samples_of_a_step_back(store_url, tmp_path, meas, m,
                                                             capsys):  # fmt: skip
    """The store's periods: the accepted samples, one period before the step and one after
    (the restart closes the open one)."""
    n = len(meas["t"])
    log = _log(tmp_path / "step.mcap", meas, _times(n, m))
    want = _truth(n, m)
    capsys.readouterr()
    assert main(["replay", str(log), "--store", store_url, "--json"]) == 0
    js = json.loads(capsys.readouterr().out)
    tc = js["time"][UNIT]
    assert (tc["clock"], tc["restarts"]) == (want["clock"], want["restarts"])
    assert js["samples"] == want["accepted"]
    with open_store(store_url) as st:
        ps = st.periods(UNIT)
        assert st.check() == []
    assert sum(p.samples for p in ps) == want["accepted"] and len(ps) == 2


# ----------------------------------------------------- an imported recording without seq


@pytest.mark.parametrize("m", [3, 5, 12, 300])
def test_import_of_a_recording_without_seq_then_its_replay(tmp_path, meas, m, capsys):
    """A Parquet recording (one time base, calendar times, no seq) whose clock steps back:
    the import refuses min(m, 5), follows the clock at the 5th and keeps the grid points
    written first (``overlap``: the m - 5 followed samples at grid points already had), so
    its log only goes forward and the log's replay accepts every row (before: the import
    dropped the m - 5 uncounted by reason, or wrote seq and t back, which the replay then
    refused as out of order)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    n = len(meas["t"])
    f = tmp_path / "rec.parquet"
    pq.write_table(pa.table({"Time": _times(n, m), **rf.rig_columns(meas)}), f)
    mp = tmp_path / "m.toml"
    mp.write_text(rf.map_text("parquet", "", '[time]\ncolumn = "Time"'))
    out = tmp_path / "rec.mcap"
    capsys.readouterr()
    assert main(["import", str(f), "--map", str(mp), "--out", str(out), "--json"]) == 0
    (res,) = json.loads(capsys.readouterr().out)["imports"]
    want = _truth(n, m)
    c = res["counts"]
    intake = {"clock": want["clock"], "refused": want["clock"]}
    assert c["intake"] == intake | ({"restarts": 1} if want["restarts"] else {})
    overlap = max(0, m - RESYNC_N)
    assert c["overlap"] == overlap and c["copied"] == want["accepted"]
    assert res["samples"] == want["accepted"] - overlap == n - m
    v = np.vstack([b.values for b in read_blocks(out)])
    names = next(iter(read_blocks(out))).names
    assert np.all(np.diff(v[:, names.index("seq")]) > 0)
    assert np.all(np.diff(v[:, names.index("t")]) > 0)
    s = replay(out)
    unit = "RIG1/rudder"
    assert s.samples == res["samples"] and s.skipped == 0
    assert not any(s.time[unit].values())
