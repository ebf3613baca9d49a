"""One structured log format for every process (issue 54): RFC 3339 times, an alarm's unit,
kind, state, value and time as fields, in JSON lines, plain text and journald's native
protocol (a real AF_UNIX datagram socket, as journald reads it)."""

from __future__ import annotations

import io
import json
import logging
import re
import socket
import struct
import subprocess
import sys

import pytest

from service.daemon.outputs import log_alarm
from service.log.setup import JournalHandler, setup_logging, under_journal

RFC3339 = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$")
ALARM = {"t": 1796378000.5361416, "kind": "leak", "state": "raised", "value": 3.93}


@pytest.fixture
def restore_root():
    root = logging.getLogger()
    saved, level = root.handlers[:], root.level
    yield
    root.handlers[:] = saved
    root.setLevel(level)


def test_json_lines_carry_rfc3339_times_and_the_alarm_fields(restore_root):
    buf = io.StringIO()
    setup_logging("INFO", stream=buf, env={})
    log_alarm("AC002/aileron_R", dict(ALARM))
    d = json.loads(buf.getvalue().splitlines()[-1])
    assert RFC3339.match(d["time"]) and d["level"] == "WARNING"
    assert d["unit"] == "AC002/aileron_R" and d["kind"] == "leak" and d["state"] == "raised"
    assert d["value"] == 3.93 and d["event_time"] == "2026-12-04T09:53:20.536Z"
    assert d["msg"] == "alarm AC002/aileron_R leak raised, value 3.93 at 2026-12-04T09:53:20.536Z"
    assert "{" not in d["msg"] and "1796378000" not in buf.getvalue()  # no dict, no epoch


def test_a_field_named_like_a_records_key_is_kept_apart(restore_root):
    buf = io.StringIO()
    setup_logging("INFO", stream=buf, env={})
    logging.getLogger("servowatch.t").info("x", extra={"fields": {"time": "T", "msg": "M"}})
    d = json.loads(buf.getvalue())
    assert RFC3339.match(d["time"]) and d["msg"] == "x"
    assert d["field_time"] == "T" and d["field_msg"] == "M"


def test_plain_text_starts_with_an_rfc3339_time_and_escapes_controls(restore_root):
    buf = io.StringIO()
    setup_logging("INFO", structured=False, stream=buf, env={})
    logging.getLogger("servowatch.t").info("key %s", "a\nb")
    line = buf.getvalue()
    assert line.count("\n") == 1
    assert RFC3339.match(line.split(" ")[0]) and line.endswith("key a\\nb\n")


def _journal_fields(data: bytes) -> dict[str, str]:
    out, pos = {}, 0
    while pos < len(data):
        nl = data.index(b"\n", pos)
        line = data[pos:nl]
        if b"=" in line:
            k, v = line.split(b"=", 1)
            out[k.decode()] = v.decode()
            pos = nl + 1
        else:  # binary form: name, newline, 64-bit length, value, newline
            n = struct.unpack("<Q", data[nl + 1 : nl + 9])[0]
            out[line.decode()] = data[nl + 9 : nl + 9 + n].decode()
            pos = nl + 9 + n + 1
    return out


def test_journald_gets_the_fields_as_journal_fields(tmp_path, restore_root):
    path = str(tmp_path / "journal")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(5)
    err = open(tmp_path / "stderr", "w")  # noqa: SIM115
    try:
        import os

        st = os.fstat(err.fileno())
        env = {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}
        assert under_journal(err, env) and not under_journal(err, {"JOURNAL_STREAM": "1:2"})
        h = setup_logging("INFO", stream=err, env=env, journal_socket=path)
        assert isinstance(h, JournalHandler)
        log_alarm("AC002/aileron_R", dict(ALARM))
        logging.getLogger("servowatch.t").info("two\nlines")
        f = _journal_fields(sock.recv(65536))
        g = _journal_fields(sock.recv(65536))
    finally:
        sock.close()
        err.close()
    assert f["PRIORITY"] == "4" and f["SYSLOG_IDENTIFIER"] == "servowatch"
    assert f["SERVOWATCH_UNIT"] == "AC002/aileron_R" and f["SERVOWATCH_KIND"] == "leak"
    assert f["SERVOWATCH_STATE"] == "raised" and float(f["SERVOWATCH_VALUE"]) == 3.93
    assert f["SERVOWATCH_EVENT_TIME"] == "2026-12-04T09:53:20.536Z"
    assert (
        RFC3339.match(f["SERVOWATCH_TIME"]) and f["SERVOWATCH_TIME"] != f["SERVOWATCH_EVENT_TIME"]
    )
    assert f["MESSAGE"].startswith("alarm AC002/aileron_R leak raised")
    assert g["MESSAGE"] == "two\nlines" and g["PRIORITY"] == "6"


def test_a_journal_that_is_gone_falls_back_to_json_lines(tmp_path, restore_root):
    err = open(tmp_path / "stderr", "w+")  # noqa: SIM115
    import os

    st = os.fstat(err.fileno())
    setup_logging("INFO", stream=err, env={"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"},
                  journal_socket=str(tmp_path / "none"))  # fmt: skip
    logging.getLogger("servowatch.t").info("still here")
    err.seek(0)
    assert json.loads(err.read().splitlines()[-1])["msg"] == "still here"
    err.close()


def test_the_actuators_final_line_and_injects_faults_read_as_words():
    from service.cli.commands.actuator import format_counters
    from service.cli.commands.inject import format_fault

    c = {"samples": 1500, "messages": 150, "faults_ok": 1, "faults_refused": 0, "late": 0,
         "seq_next": 1500}  # fmt: skip
    assert format_counters(c) == ("1500 samples in 150 messages, 1 fault applied, 0 refused, "
                                  "0 late bursts, next seq 1500")  # fmt: skip
    leak = {"kind": "leak", "value": 6.1e-13, "target": 8e-13, "until": None}
    assert format_fault(leak) == "leak 6.1e-13 m^3/(s Pa), ramping to 8e-13, until cleared"
    drop = {"kind": "dropout", "channel": "p1", "until": 1796378000.5361416}
    assert format_fault(drop) == "dropout of p1, until 2026-12-04T09:53:20.536Z"
    assert "{" not in format_fault({"kind": "sensor_bias", "channel": "x_s", "value": 1e-4,
                                    "until": 12.5})  # fmt: skip


@pytest.mark.slow
def test_the_actuator_logs_as_the_daemon_does(net):
    """The virtual actuator's log lines are the daemon's JSON lines (RFC 3339 times), and its
    final line has no dict in it."""
    p = net.start("actuator", "--duration", "0.5", "--rate", "200")
    _, err = p.communicate(timeout=120)
    assert p.returncode == 0, err
    recs = [json.loads(ln) for ln in err.splitlines()]  # every line a JSON record
    assert recs and all(RFC3339.match(r["time"]) for r in recs), err
    starts = [r for r in recs if r["logger"] == "servowatch.actuator"]
    assert starts[0]["msg"].startswith("actuator AC001/elevator_L publishing"), err
    final = recs[-1]  # its final line: the counters in words and as fields
    assert final["msg"].startswith("actuator AC001/elevator_L stopped: "), final
    assert "{" not in final["msg"] and "samples in" in final["msg"], final
    assert final["unit"] == "AC001/elevator_L" and final["samples"] > 0, final
    assert f"{final['samples']} samples in {final['messages']} messages" in final["msg"]


def test_listen_count_prints_exactly_n_outputs_with_readable_times():
    """``listen --count 6`` printed 153 lines (issue 54): the outputs that arrive after the
    N-th, before the subscribers go, are not printed."""
    from service.cli.commands.listen import OutputListener

    out = io.StringIO()
    lis = OutputListener(count=6, out=out)
    for k in range(20):  # a burst: more arrive than asked for
        lis.on_sample("fleet/AC1/x/health", json.dumps({"t": 1796378000.5 + k,
                      "leak_ratio": 1.0}).encode(), None)  # fmt: skip
    lines = out.getvalue().splitlines()
    assert len(lines) == 6 and lis.done.is_set() and lis.summary()["received"] == 6
    assert lines[0].startswith("2026-12-04T09:53:20.500Z fleet/AC1/x/health {")
    assert json.loads(lines[5].split(" ", 2)[2])["t"] == 1796378005.5


def test_version():
    from importlib.metadata import version

    r = subprocess.run([sys.executable, "-m", "service.cli", "--version"], capture_output=True,
                       text=True, timeout=60)  # fmt: skip
    assert r.returncode == 0 and r.stdout.strip() == f"servowatch {version('servowatch')}"


def test_replays_summary_shows_calendar_times_not_epoch_floats(capsys):
    from types import SimpleNamespace

    from service.cli.commands.replay import _print_summary

    s = SimpleNamespace(
        speed=None, log="x.mcap", samples=10, actuators=["AC1/x"], duration_s=1.0, wall_s=0.1,
        final={"AC1/x": {"t": 1796378000.5361416, "est": {"c_lk": 1e-12}, "health": {}}},
        alarms=[{"t": 1796378000.25, "actuator": "AC1/x", "kind": "leak", "state": "raised",
                 "value": 3.93}], time={}, corrupt_chunks=0, source=None, out=None,
        warnings=[],
    )  # fmt: skip
    _print_summary(s)
    out = capsys.readouterr().out
    assert "1796378000" not in out and "AC1/x at 2026-12-04T09:53:20.536Z" in out
    assert "2026-12-04T09:53:20.250Z: AC1/x leak raised (3.93)" in out
