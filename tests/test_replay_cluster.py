"""``replay --cluster`` (issue 53): a batch on a real Dask scheduler and two ``dask worker``
processes on loopback gives the store of a one-process replay, also when a worker is killed
with SIGKILL mid-batch; an unreachable scheduler is one line, exit 3, nothing written; logs
by path and ``file://`` URL; every server socket on 127.0.0.1. Real logs of the HF bench
(3 s each) through the real monitor; SQLite and PostgreSQL."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import test_ingest
from test_ingest import DAY, T0, _fresh, _log, _rul_json, _snapshot

from service.cli import main
from service.replay import log_order, replay_many

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
ACTS = ("ail_L", "ail_R", "elev", "rud")
meas = test_ingest.meas  # the fixture: 3 s of the healthy HF bench, 1 kHz


def unit_command(unit: str, **subst: str) -> list[str]:
    """The ``ExecStart`` of a ``deploy/dask`` systemd unit as argv, run by this Python,
    with ``subst`` replacing words (the scheduler's port, the worker's name, its folder)."""
    line = next(x for x in (ROOT / "deploy" / "dask" / unit).read_text().splitlines()
                if x.startswith("ExecStart="))  # fmt: skip
    argv = line.removeprefix("ExecStart=").split()
    assert argv[:3] == ["/opt/servowatch/.venv/bin/python", "-m", "dask"], argv
    for k, v in subst.items():
        argv = [a.replace(k, v) for a in argv]
    return argv[3:]


class DaskProcs:
    """A ``dask scheduler`` and ``dask worker`` processes as ``deploy/dask``'s systemd units
    start them (127.0.0.1, dashboards off), on a free port."""

    def __init__(self, folder: Path, workers: int = 2) -> None:
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs = folder
        try:
            self._up(folder, workers)
        except BaseException:
            self.close()  # nothing left running
            raise

    def _up(self, folder: Path, workers: int) -> None:
        import socket

        for _ in range(20):
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                port = str(s.getsockname()[1])
            self._start("scheduler", unit_command("servowatch-dask-scheduler.service",
                                                  **{"8786": port}))  # fmt: skip
            self.address = f"tcp://127.0.0.1:{port}"
            try:
                self.wait_workers(0)
                break
            except OSError:  # the port was taken meanwhile: another
                self.procs.pop("scheduler").kill()
        for k in range(1, workers + 1):
            self._start(f"w{k}", unit_command(
                "servowatch-dask-worker@.service", **{"8786": port, "%H-%i": f"w{k}",
                "/var/lib/servowatch-dask/worker-%i": str(folder / f"w{k}")}))  # fmt: skip
        self.wait_workers(workers)

    def _start(self, name: str, args: list[str]) -> None:
        err = open(self.logs / f"{name}.err", "w")  # noqa: SIM115 - closed with the process
        self.procs[name] = subprocess.Popen([sys.executable, "-m", "dask", *args], cwd=ROOT,
                                            env=ENV, stdout=err, stderr=err)  # fmt: skip

    def client(self):
        from distributed import Client

        return Client(self.address, timeout="30s")

    def wait_workers(self, n: int) -> None:
        with self.client() as c:
            if n:
                c.wait_for_workers(n, timeout=120)

    def close(self) -> None:
        for p in reversed(list(self.procs.values())):  # the workers, then the scheduler
            if p.poll() is None:
                p.terminate()
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


@pytest.fixture(scope="module")
def dask_procs(tmp_path_factory):
    d = DaskProcs(tmp_path_factory.mktemp("dask"))
    yield d
    d.close()


def _logs(folder: Path, meas, n: int = 3, acts=ACTS) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    return [_log(folder / f"{a}-{k:02d}.mcap", meas, T0 + k * DAY, act=a)
            for k in range(n) for a in acts]  # fmt: skip


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "service.cli", *args]


def _fleet_json(url, capsys) -> list:
    capsys.readouterr()
    assert main(["fleet", "--store", str(url), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)

    def strip(x):
        if isinstance(x, dict):
            return {k: strip(v) for k, v in x.items() if not k.endswith(("updated_s", "wall_s"))
                    and k != "store"}  # fmt: skip
        if isinstance(x, list):
            return [strip(v) for v in x]
        return x

    return strip(rows)


def _views(url, capsys) -> tuple:
    """What a reader sees: ``fleet --json`` and ``rul --json`` (wall-clock fields dropped),
    and every stored period, flight and alarm."""
    return _fleet_json(url, capsys), _rul_json(url, capsys), _snapshot(url)


def _reference(request, store_url, tmp_path, logs, capsys) -> tuple:
    ref = _fresh(request, store_url, tmp_path, "ref")
    replay_many(log_order(logs), ref)
    return _views(ref, capsys)


# --------------------------------------------------------------------- 1. the same store


@pytest.mark.slow
def test_a_batch_on_two_dask_workers_stores_what_one_process_does(request, store_url, tmp_path,
                                                                   meas, capsys, dask_procs):  # fmt: skip
    logs = _logs(tmp_path / "logs", meas)
    ref = _reference(request, store_url, tmp_path, logs, capsys)
    got = _fresh(request, store_url, tmp_path, "got")
    r = subprocess.run(_cli("replay", str(tmp_path / "logs"), "--store", got, "--cluster",
                            dask_procs.address, "--json"), cwd=ROOT, env=ENV,
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["logs"] == 12 and out["failed"] == []
    assert _views(got, capsys) == ref
    # the summary names the workers and what each did: all 12 logs, by the two workers
    w = out["workers"]
    assert sum(d["logs"] for d in w.values()) == 12
    assert sum(d["samples"] for d in w.values()) == out["samples"] > 12 * 2900
    with dask_procs.client() as c:
        assert set(w) <= set(c.scheduler_info()["workers"])
    # again: nothing added (compared with the views after the first, which `rul` wrote to)
    ref = _views(got, capsys)
    r = subprocess.run(_cli("replay", str(tmp_path / "logs"), "--store", got, "--cluster",
                            dask_procs.address, "--json"), cwd=ROOT, env=ENV,
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0 and json.loads(r.stdout)["periods_new"] == 0
    assert _views(got, capsys) == ref


@pytest.mark.slow
def test_a_worker_killed_mid_batch_loses_and_doubles_nothing(request, store_url, tmp_path, meas,
                                                             capsys):  # fmt: skip
    logs = _logs(tmp_path / "logs", meas, n=4)
    ref = _reference(request, store_url, tmp_path, logs, capsys)
    got = _fresh(request, store_url, tmp_path, "got")
    (tmp_path / "dask").mkdir()
    procs = DaskProcs(tmp_path / "dask")
    try:
        p = subprocess.Popen(_cli("replay", str(tmp_path / "logs"), "--store", got, "--cluster",
                                  procs.address, "--json"), cwd=ROOT, env=ENV,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
        killed = None
        with procs.client() as c:
            end = time.monotonic() + 120
            while killed is None and time.monotonic() < end and p.poll() is None:
                info = c.scheduler_info()["workers"]
                for addr, keys in c.processing().items():
                    if keys and info.get(addr, {}).get("name") == "w1":
                        procs.procs["w1"].send_signal(signal.SIGKILL)  # holding a task
                        killed = addr
                time.sleep(0.01)
        assert killed is not None, "w1 never held a task"
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
        res = json.loads(out)
        assert res["logs"] == 16 and res["failed"] == []
        assert killed not in res["workers"] or res["workers"][killed]["logs"] < 16
        assert sum(d["logs"] for d in res["workers"].values()) == 16
        assert _views(got, capsys) == ref
    finally:
        procs.close()


# ------------------------------------------------------------------- 2. what fails, fails


def test_an_unreachable_scheduler_is_one_line_exit_3_and_nothing_written(tmp_path, meas):
    import socket

    logs = _logs(tmp_path / "logs", meas, n=1, acts=ACTS[:2])
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nothing listens there once closed
    store = tmp_path / "h.sqlite"
    t0 = time.monotonic()
    r = subprocess.run(_cli("replay", *map(str, logs), "--store", str(store), "--cluster",
                            f"tcp://127.0.0.1:{port}"), cwd=ROOT, env=ENV,
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 3
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("servowatch: error: --cluster tcp://127.0.0.1")
    assert "no Dask scheduler reachable" in lines[0]
    assert not store.exists() and not list(tmp_path.glob("h.sqlite*"))
    assert time.monotonic() - t0 < 60


@pytest.mark.slow
def test_a_bad_file_on_the_cluster_is_named_and_the_rest_stored(tmp_path, meas, capsys,
                                                                 dask_procs):  # fmt: skip
    logs = _logs(tmp_path / "logs", meas, n=2, acts=ACTS[:2])
    (tmp_path / "logs" / "notes.mcap").write_text("not a log\n")
    store = tmp_path / "h.sqlite"
    capsys.readouterr()
    rc = main(["replay", str(tmp_path / "logs"), "--store", str(store), "--cluster",
               dask_procs.address, "--json"])  # fmt: skip
    out = json.loads(capsys.readouterr().out)
    assert rc == 1 and [Path(f["log"]).name for f in out["failed"]] == ["notes.mcap"]
    assert out["failed"][0]["error"].startswith(str(tmp_path / "logs" / "notes.mcap"))
    assert out["actuators"] == {
        "AC1/ail_L": {"flights": 2, "first": 0, "last": 1},
        "AC1/ail_R": {"flights": 2, "first": 0, "last": 1},
    }
    assert len(logs) == 4 and sum(d["logs"] for d in out["workers"].values()) == 5


@pytest.mark.slow
def test_tasks_of_one_log_each_store_and_report_what_one_process_does(tmp_path, meas, capsys,
                                                                      dask_procs, monkeypatch):  # fmt: skip
    """``--task-logs 1``: an actuator's logs on both workers at once, written in their
    group's order: the same store, the summary's flights the final ones, and every write
    after a unit's first an append (no read of its history)."""
    import service.store.ingest as ingest_mod

    appended: list[bool] = []
    real = ingest_mod.renumber_append
    monkeypatch.setattr(ingest_mod, "renumber_append",
                        lambda *a: appended.append(real(*a)) or appended[-1])  # fmt: skip
    logs = _logs(tmp_path / "logs", meas, n=4, acts=ACTS[:2])
    one, got = tmp_path / "one.sqlite", tmp_path / "got.sqlite"
    capsys.readouterr()
    assert main(["replay", str(tmp_path / "logs"), "--store", str(one), "--json"]) == 0
    ref = json.loads(capsys.readouterr().out)
    rc = main(["replay", str(tmp_path / "logs"), "--store", str(got), "--cluster",
               dask_procs.address, "--task-logs", "1", "--json"])  # fmt: skip
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["actuators"] == ref["actuators"] and len(logs) == 8
    assert out["actuators"]["AC1/ail_L"] == {"flights": 4, "first": 0, "last": 3}
    assert sum(d["tasks"] for d in out["workers"].values()) == 8
    assert _snapshot(got) == _snapshot(one)
    assert appended.count(True) >= 6  # both units' first write (an empty history) whole


def test_a_groups_tasks_are_written_in_their_order_whatever_completes_first():
    from service.replay.cluster import in_group_order

    futs = [object() for _ in range(7)]
    rank = [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (2, 0), (0, 3)]
    done = [futs[i] for i in (2, 4, 5, 1, 3, 0, 6)]  # completion order
    got = [futs.index(f) for f in in_group_order(iter(done), futs, rank)]
    assert got == [5, 3, 4, 0, 1, 2, 6]


# -------------------------------------------------------------- 3. logs by URL, loopback


@pytest.mark.slow
def test_file_urls_store_what_paths_do(tmp_path, meas, capsys, dask_procs):
    logs = _logs(tmp_path / "logs", meas, n=2, acts=ACTS[:2])
    by_path, by_url = tmp_path / "a.sqlite", tmp_path / "b.sqlite"
    replay_many(log_order(logs), by_path)
    capsys.readouterr()
    rc = main(["replay", (tmp_path / "logs").as_uri(), "--store", str(by_url), "--cluster",
               dask_procs.address, "--json"])  # fmt: skip
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["logs"] == 4 and out["failed"] == []
    assert _snapshot(by_url) == _snapshot(by_path)
    # one file's URL, and a glob of them
    rc = main(
        [
            "replay",
            logs[0].as_uri(),
            (tmp_path / "logs").as_uri() + "/ail_R-*.mcap",
            "--store",
            str(tmp_path / "c.sqlite"),
            "--cluster",
            dask_procs.address,
            "--json",
        ]
    )
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["logs"] == 3 and out["failed"] == []


@pytest.mark.slow
def test_the_scheduler_and_workers_listen_on_loopback_only(dask_procs):
    import psutil

    seen = []
    for name, p in dask_procs.procs.items():
        for c in psutil.Process(p.pid).net_connections(kind="inet"):
            if c.status == psutil.CONN_LISTEN:
                seen.append((name, c.laddr.ip))
    assert {n for n, _ in seen} == {"scheduler", "w1", "w2"}
    assert {ip for _, ip in seen} == {"127.0.0.1"}, seen


# ------------------------------------------------------ 4. the client's batched writes


def test_a_task_written_in_one_transaction_stores_what_its_logs_do_one_by_one(
    request, store_url, tmp_path, meas, capsys
):
    """``write_logs`` (``HealthStore.ingest_logs``: a task's logs in one transaction, each
    unit renumbered once) gives the store, and the flights, of one ``ingest_log`` per log;
    a copy of a log in the same batch adds nothing."""
    from service.replay.cluster import GroupTask, run_group, write_logs
    from service.store import open_store

    logs = log_order(_logs(tmp_path / "logs", meas, n=3, acts=ACTS[:2]))
    (tmp_path / "logs" / "copy.mcap").write_bytes(logs[0].read_bytes())
    ref = _reference(request, store_url, tmp_path, logs, capsys)
    got = _fresh(request, store_url, tmp_path, "got")
    res = run_group(GroupTask([str(p) for p in logs] + [str(tmp_path / "logs" / "copy.mcap")],
                              str(got), {}, 1800.0, {}, replay_many))  # fmt: skip
    assert [e for _, _, e, _ in res.logs] == [None] * 7
    done = [(s, c) for _, s, _, c in res.logs]
    assert all(s.periods_new == 0 for s, _ in done)  # not written on the worker
    with open_store(got) as hs:
        write_logs(hs, done)
    assert _views(got, capsys) == ref
    assert [s.stored for s, _ in done][-1] == {"AC1/ail_L": "stored"}
    assert sum(s.periods_new for s, _ in done[:-1]) > 0 and done[-1][0].periods_new == 0
    one = {a: f for s, _ in done[:-1] for a, f in s.flights.items() if s.log == str(logs[-1])}
    assert one == {"AC1/ail_R": [2]}  # the final flight numbers (days 0, 1, 2)


def test_a_log_by_another_protocol_is_fetched_under_its_own_name(tmp_path, meas):
    """A URL of a protocol other than the local files' (fsspec's in-process ``memory://``
    here) is copied under its own file name: the task stores what the path gives, and names
    the URL, not the copy."""
    import fsspec

    from service.replay.cluster import GroupTask, log_facts, run_group

    log = _log(tmp_path / "ail_L-00.mcap", meas, T0)
    url = "memory://fleet/logs/ail_L-00.mcap"
    with fsspec.open(url, "wb") as fh:
        fh.write(log.read_bytes())
    assert log_facts(url).units == log_facts(str(log)).units == ["AC1/ail_L"]
    by_url, by_path = (run_group(GroupTask([x], "s", {}, 1800.0, {}, replay_many)).logs[0]
                       for x in (url, str(log)))  # fmt: skip
    assert by_url[0] == by_url[1].log == url and by_url[2] is None

    def ident(call):  # a unit's source is its stream identity (service.store.identity)
        return [(u.actuator, u.source, u.samples, u.name) for u in call.units]

    assert ident(by_url[3]) == ident(by_path[3])  # the same identity and file name
    assert by_url[3].periods == by_path[3].periods
    with fsspec.open("memory://fleet/logs/notes.mcap", "wb") as fh:
        fh.write(b"not a log\n")
    bad = run_group(GroupTask(["memory://fleet/logs/notes.mcap", "memory://fleet/none.mcap"],
                              "s", {}, 1800.0, {}, replay_many)).logs  # fmt: skip
    assert [b[2].split(": ")[0] for b in bad] == ["memory://fleet/logs/notes.mcap",
                                                  "memory://fleet/none.mcap"]  # fmt: skip


def test_logs_over_http_on_loopback_are_listed_fetched_and_stored_as_paths(tmp_path, meas):
    """``http://`` (fsspec's HTTP file system, aiohttp) from a server on 127.0.0.1: a folder
    URL lists its logs from the server's index, and each log's task gives what its path
    gives, named by its URL."""
    import functools
    import threading
    from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

    from service.replay.cluster import GroupTask, expand_urls, log_facts, run_group

    logs = _logs(tmp_path / "logs", meas, n=2, acts=ACTS[:1])
    quiet = type("Quiet", (SimpleHTTPRequestHandler,), {"log_message": lambda *a: None})
    srv = ThreadingHTTPServer(("127.0.0.1", 0),
                              functools.partial(quiet, directory=str(tmp_path / "logs")))  # fmt: skip
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        base = f"http://127.0.0.1:{srv.server_address[1]}/"
        urls = expand_urls(base)
        assert urls == [base + p.name for p in sorted(logs)]
        assert [log_facts(u).units for u in urls] == [log_facts(str(p)).units for p in logs]
        by_url = run_group(GroupTask(urls, "s", {}, 1800.0, {}, replay_many)).logs
        by_path = run_group(GroupTask([str(p) for p in sorted(logs)], "s", {}, 1800.0, {},
                                      replay_many)).logs  # fmt: skip
    finally:
        srv.shutdown()
        srv.server_close()
    assert [x[0] for x in by_url] == [x[1].log for x in by_url] == urls
    assert all(x[2] is None for x in by_url)
    for u, p in zip(by_url, by_path, strict=True):
        assert [(x.source, x.samples, x.name) for x in u[3].units] == [
            (x.source, x.samples, x.name) for x in p[3].units]  # fmt: skip
        assert u[3].periods == p[3].periods


@pytest.mark.slow
def test_the_progress_counts_every_log_from_the_completed_tasks(tmp_path, meas, dask_procs):
    """``run_batch``'s ``tick`` (the progress bar's) once per log as its task completes, and
    ``on_log`` once per log; the report names the scheduler's workers."""
    from service.replay.cluster import BatchReport, DaskPool, run_batch

    logs = _logs(tmp_path / "logs", meas, n=2, acts=ACTS[:3])
    ticks, seen = [], []
    report = BatchReport()
    pool = DaskPool(dask_procs.address)
    try:
        out = run_batch(logs, tmp_path / "h.sqlite", pool, flight_gap_s=1800.0, kw={},
                        work=replay_many, report=report, task_logs=1,
                        tick=lambda: ticks.append(time.monotonic()),
                        on_log=lambda p, s, e: seen.append((p, e)))  # fmt: skip
    finally:
        pool.close()
    assert len(ticks) == len(out) == 6 and sorted(p for p, _ in seen) == sorted(logs)
    assert all(e is None for _, e in seen)
    assert report.pool.startswith("Dask scheduler tcp://127.0.0.1:")
    assert sum(w.tasks for w in report.workers.values()) == 6
    assert sum(w.logs for w in report.workers.values()) == 6
