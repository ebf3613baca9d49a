"""One log format for every process (issue 54): the station's long-running commands (``run``,
``actuator``, ``router``, ``web``) write only log lines on stderr, each one JSON record with
an RFC 3339 time (``--plain-logs``: ``TIME LEVEL LOGGER MESSAGE``), and their facts (the
page's URL, the router's endpoints, the counters at the end) as fields; the processes they
start (the warm-up's parts, the MCAP log process, workers) log as their parent does."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from loglines import check_json_lines, check_plain_lines, find_in

from service.zenoh_util import free_port, loopback

ROOT = Path(__file__).resolve().parent.parent


def _start(tmp: Path, tag: str, *args: str) -> subprocess.Popen:
    with (tmp / f"{tag}.out").open("w") as out, (tmp / f"{tag}.err").open("w") as err:
        return subprocess.Popen(
            [sys.executable, "-m", "service.cli", *args], stdout=out, stderr=err, cwd=tmp,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip


def _wait(pred, what: str, procs: list[subprocess.Popen], timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        dead = [p.args for p in procs if p.poll() is not None]
        assert not dead and time.monotonic() < deadline, f"waiting for {what}: {dead}"
        time.sleep(0.1)


def _station(tmp: Path, *plain: str) -> dict[str, tuple[str, str]]:
    """router, daemon, actuator and page started, used a little, stopped with SIGTERM: each
    one's (stdout, stderr)."""
    from service.store import open_store

    open_store(tmp / "s.sqlite").close()
    ep = loopback(free_port())
    procs = {"router": _start(tmp, "router", "router", "--listen", ep, *plain)}
    try:
        _wait(lambda: find_in(tmp / "router.err", "servowatch.router", "listen") is not None
              or (plain and "listening on" in (tmp / "router.err").read_text()),
              "the router", list(procs.values()))  # fmt: skip
        procs["run"] = _start(tmp, "run", "run", "--connect", ep, "--log", str(tmp / "r.mcap"),
                              "--store", str(tmp / "s.sqlite"), "--no-rotate", *plain)  # fmt: skip
        procs["web"] = _start(tmp, "web", "web", "--store", str(tmp / "s.sqlite"), "--listen",
                              "127.0.0.1:0", "--access-log", *plain)  # fmt: skip
        _wait(
            lambda: " started on " in (tmp / "run.err").read_text(),
            "the daemon",
            list(procs.values()),
            timeout=600,
        )  # a cold numba cache compiles first
        procs["actuator"] = _start(tmp, "actuator", "actuator", "--connect", ep, "--rate", "200",
                                   "--duration", "3", *plain)  # fmt: skip
        _wait(lambda: "serving http://" in (tmp / "web.err").read_text(), "the page",
              list(procs.values()))  # fmt: skip
        text = (tmp / "web.err").read_text()
        url = text[text.index("serving http://") + 8 :].split()[0]
        with urllib.request.urlopen(url + "healthz", timeout=10) as r:
            assert r.status == 200
        assert procs["actuator"].wait(120) == 0, (tmp / "actuator.err").read_text()
        time.sleep(1.0)
        for name in ("web", "run", "router"):
            procs[name].send_signal(signal.SIGTERM)
            assert procs[name].wait(60) == 0, (tmp / f"{name}.err").read_text()[-3000:]
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait(10)
    return {n: ((tmp / f"{n}.out").read_text(), (tmp / f"{n}.err").read_text()) for n in procs}


@pytest.mark.slow
def test_the_station_logs_json_lines_with_rfc3339_times(tmp_path):
    got = _station(tmp_path)
    recs = {}
    for name, (out, err) in got.items():
        assert out == "", (name, out)  # nothing but log lines, and those on stderr
        recs[name] = check_json_lines(err)
        assert recs[name], name
    router = recs["router"]
    assert router[0]["msg"] == f"router {router[0]['zid']} listening on {router[0]['listen'][0]}"
    assert router[-1]["msg"] == "router stopped"
    web = recs["web"]
    serving = next(r for r in web if "url" in r)
    assert serving["msg"] == f"serving {serving['url']} from {serving['store']}"
    access = [r for r in web if r["logger"] == "servowatch.web.access"]
    assert access and access[0]["status"] == 200 and access[0]["request"].startswith("GET /healthz")
    assert web[-1]["msg"] == "web stopped"
    act = recs["actuator"][-1]
    assert act["msg"].startswith("actuator AC001/elevator_L stopped: ") and act["samples"] > 0
    stopped = next(r for r in recs["run"] if r["msg"].startswith("daemon stopped: "))
    assert stopped["msg"] == (f"daemon stopped: {stopped['samples']} samples, "
                              f"{stopped['dropped']} dropped, {stopped['bad']} bad")  # fmt: skip
    assert stopped["samples"] > 0
    last = recs["run"][-1]  # the file it logged to, not every name it wrote
    assert last["msg"] == f"logged to {last['log_file']} (1 file of this run kept)", last
    assert Path(last["log_file"]).is_file() and last["deleted_files"] == 0


@pytest.mark.slow
def test_plain_logs_are_time_level_logger_message(tmp_path):
    got = _station(tmp_path, "--plain-logs")
    for name, (out, err) in got.items():
        assert out == "", (name, out)
        lines = check_plain_lines(err)
        assert lines and all(lg.startswith("servowatch.") for _, _, lg, _ in lines), err
    assert "router stopped" in got["router"][1] and "web stopped" in got["web"][1]


def test_a_child_process_logs_as_its_parent():
    """``setup_logging`` on the process's stderr exports its format and level; a child (the
    MCAP log process, a warm-up part, a replay worker) reads them with ``inherit_logging``."""
    code = ("import logging, os, subprocess, sys\n"
            "from service.log.setup import setup_logging\n"
            "setup_logging('INFO', structured=sys.argv[1] == 'json')\n"
            "child = 'from service.log.setup import inherit_logging; import logging; "
            "inherit_logging(); logging.getLogger(\"servowatch.x\").info(\"child %d\", 7)'\n"
            "subprocess.run([sys.executable, '-c', child], check=True)\n")  # fmt: skip
    for fmt in ("json", "plain"):
        r = subprocess.run([sys.executable, "-c", code, fmt], capture_output=True, text=True,
                           timeout=60, cwd=ROOT)  # fmt: skip
        assert r.returncode == 0, r.stderr
        if fmt == "json":
            (rec,) = check_json_lines(r.stderr)
            assert rec["msg"] == "child 7" and rec["level"] == "INFO", rec
        else:
            ((_, level, logger, msg),) = check_plain_lines(r.stderr)
            assert (level, logger, msg) == ("INFO", "servowatch.x", "child 7")


@pytest.mark.slow
def test_a_services_cold_compile_is_logged_in_its_format(tmp_path):
    """A service's first start compiles (``ensure(..., log=True)``): the announcement, each
    kernel's line (from the warm-up's part processes) and the end are its JSON lines."""
    code = ("from service.log.setup import setup_logging\n"
            "from service.cli.warmup import ensure\n"
            "setup_logging('INFO')\n"
            "ensure('models', 'trend', jobs=2, log=True)\n")  # fmt: skip
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                       cwd=ROOT, env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)})  # fmt: skip
    assert r.returncode == 0, r.stderr
    recs = check_json_lines(r.stderr)
    assert recs[0]["msg"].startswith("compiling the HF bench kernels, the RUL's trend model "
                                     "kernel (first run, about")  # fmt: skip
    kernels = [r["kernel"] for r in recs if "kernel" in r]
    assert "models.compiled._integrate_hf" in kernels
    assert "service.prognostics.trend._kalman" in kernels and len(set(kernels)) == len(kernels)
    assert recs[-1]["msg"].startswith("kernels compiled in ")
    assert json.dumps(recs)  # fields are plain JSON


def test_the_daemons_last_line_names_its_last_file_and_counts_the_rest(tmp_path, caplog):
    """A station that runs for months writes hundreds of files: the last line names the last
    one and counts those kept and those retention deleted (it listed every name it wrote)."""
    from service.cli.commands.run import log_files_line

    paths = [str(tmp_path / f"r-{k:04d}.mcap") for k in range(5)]
    for p in paths[3:]:
        Path(p).write_bytes(b"x")
    with caplog.at_level("INFO", logger="servowatch.daemon"):
        log_files_line(paths)
    (rec,) = caplog.records
    assert rec.getMessage() == (f"logged to {paths[-1]} (2 files of this run kept, 3 deleted "
                                "by retention)")  # fmt: skip
    assert rec.fields == {"log_file": paths[-1], "kept_files": 2, "deleted_files": 3}


def _warn(text: str) -> str:
    """A task that logs a warning (run on a pool's worker)."""
    import logging

    logging.getLogger("servowatch.replay").warning("worker says %s", text)
    return text


@pytest.mark.slow
@pytest.mark.parametrize("pool", ["jobs", "dask"])
def test_a_batch_workers_log_lines_are_the_batchs(pool):
    """A warning logged in a ``replay --jobs`` worker or a ``--cluster local:N`` Dask worker
    is a line of the batch's format (JSON here), not Python's bare last-resort line."""
    code = ("import sys\n"
            "sys.path.insert(0, 'tests')\n"
            "from service.log.setup import setup_logging\n"
            "from service.replay.cluster import open_pool\n"
            "from test_process_logs import _warn\n"
            "setup_logging('INFO')\n"
            "pool = open_pool(2, 'local:1' if sys.argv[1] == 'dask' else None)\n"
            "pool.start(1)\n"
            "f = pool.submit(_warn, 'hello')\n"
            "assert [x.result() for x in pool.as_completed([f])] == ['hello']\n"
            "pool.close()\n")  # fmt: skip
    r = subprocess.run([sys.executable, "-c", code, pool], capture_output=True, text=True,
                       timeout=300, cwd=ROOT)  # fmt: skip
    assert r.returncode == 0, r.stderr
    (line,) = [ln for ln in r.stderr.splitlines() if "worker says" in ln]
    (rec,) = check_json_lines(line)
    assert rec["msg"] == "worker says hello" and rec["logger"] == "servowatch.replay", rec
