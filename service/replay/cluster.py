"""A batch of logs on a pool of workers: ``replay --jobs N`` (local processes) and ``replay
--cluster tcp://HOST:PORT | local:N`` (Dask distributed). One code path for both.

The work unit is a group of logs that share no actuator with another group (``groups``),
each group's logs in life order. A task (``run_group``) replays its logs with
``service.replay.replay_many``, the per-log work function of a one-process batch, on a
``CaptureStore``: the actuators' baselines travel with the task, and each log's store write
(``HealthStore.ingest_log``'s arguments) is captured and returned instead of written. The
client writes every log through ``HealthStore.ingest_log`` as the tasks complete
(``as_completed``): one writer, any backend, and a task retried after its worker died adds
nothing, since only a finished task's result is written, once (decision record 0039).
"""

from __future__ import annotations

import logging
import os
import re
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "CaptureStore",
    "ClusterError",
    "DaskPool",
    "ProcessPool",
    "groups",
    "open_pool",
    "run_batch",
    "run_group",
]

log = logging.getLogger("servowatch.replay")


class ClusterError(RuntimeError):
    """A Dask scheduler that cannot be reached (or a ``--cluster`` value that names none)."""


# ------------------------------------------------------------------------ logs and groups


def is_url(item: str | Path) -> bool:
    """``item`` is an fsspec URL (``scheme://...``), not a local path."""
    s = str(item)
    return "://" in s and s.split("://", 1)[0].replace("+", "").replace("-", "").isalnum()


def local_path(item: str | Path) -> Path | None:
    """The local path of a plain path or a ``file://`` URL; None for another URL."""
    s = str(item)
    if not is_url(s):
        return Path(s)
    if s.startswith("file://"):
        from fsspec.implementations.local import LocalFileSystem

        return Path(LocalFileSystem._strip_protocol(s))
    return None


def expand_urls(item: str) -> list[str]:
    """The logs an fsspec URL names, as URLs: a file, a folder (its ``*.mcap`` files,
    recursively) or a glob pattern, listed where this runs (the client must be able to list
    the location; the workers read the files). FileNotFoundError names an item that
    matches nothing."""
    import fsspec

    try:
        fs, path = fsspec.core.url_to_fs(item)
        if any(c in path for c in "*?["):
            found = sorted(f for f in fs.glob(path) if fs.isfile(f))
        elif fs.isdir(path):
            found = sorted(f for f in fs.find(path) if f.endswith(".mcap"))
        else:
            found = [path] if fs.isfile(path) else []
    except (ImportError, ValueError) as e:  # an unknown protocol, its package missing
        raise FileNotFoundError(f"{item}: cannot list it: {e}") from None
    if not found:
        raise FileNotFoundError(f"{item}: no such log, folder or matching file")
    return [item if f == path and not fs.isdir(path) else fs.unstrip_protocol(f)
            for f in found]  # fmt: skip


def fetch(item: str, cache: str) -> Path:
    """A local file holding log ``item``: the path itself (a path, ``file://``), else a copy
    under ``cache`` with the same file name (fsspec ``simplecache``: s3://, gs://, http://,
    any protocol the worker has installed), so the log's name in the store is the same."""
    p = local_path(item)
    if p is not None:
        return p
    import fsspec

    return Path(fsspec.open_local(f"simplecache::{item}",
                                  simplecache={"cache_storage": cache, "same_names": True}))  # fmt: skip


@dataclass
class LogFacts:
    """What the client needs of a log before the work: its units (``{aircraft}/{actuator}``,
    ``?path`` for a file that is not a readable log) and its place in life order."""

    units: list[str]
    order: tuple


def order_key(path: Path, name: str, recs: list | None = None) -> tuple:
    """A log's place in life order (``service.replay.log_order``): by its flight record's
    calendar start, then its flight number, then by ``name`` (digits compared as numbers).
    ``recs``: the log's flight records when the caller has the log open already."""
    from service.log.logfile import LogSet
    from service.store.lifeorder import natural_key

    if recs is None:
        try:
            with LogSet(path) as ls:
                recs = ls.files[0].flight_records
        except (ValueError, IndexError, OSError):  # a malformed record: fails when replayed
            recs = []
    natural = natural_key(name)
    if recs and recs[0].start_unix is not None:
        return (0, recs[0].start_unix, recs[0].flight, natural)
    if recs:
        return (1, 0.0, recs[0].flight, natural)
    return (2, 0.0, 0, natural)


def log_facts(item: str) -> LogFacts:
    """``LogFacts`` of log ``item`` (a path or URL), read where this runs (the client for
    local logs, a worker for other URLs); its first file opened once (``LogSet``)."""
    import tempfile

    from service.log.logfile import LogSet

    with tempfile.TemporaryDirectory(prefix="servowatch-logs-") as cache:
        try:
            p = fetch(item, cache)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                with LogSet(p) as ls:
                    first = ls.files[0]
                    first.check()
                    units = [f"{a}/{b}" for a, b in first.units]
                    try:
                        recs = first.flight_records
                    except ValueError:  # a malformed record: the file fails when replayed
                        recs = []
        except Exception:  # not a log: it fails in its task, alone
            return LogFacts([f"?{item}"], order_key(Path("/nonexistent"), item, []))
        return LogFacts(units, order_key(p, item, recs))


def groups(items: list[str], facts: dict[str, LogFacts]) -> list[list[str]]:
    """``items`` split into groups that share no actuator (by the logs' meas topics), each in
    the given order (a file that is not a readable log: a group of its own); largest first."""
    parent: dict[str, str] = {}

    def find(a: str) -> str:
        while parent.setdefault(a, a) != a:
            a = parent[a]
        return a

    names = []
    for p in items:
        units = facts[p].units or ["?"]  # a log without a unit: one group for all of them
        for u in units[1:]:
            parent[find(u)] = find(units[0])
        names.append(units[0])
    out: dict[str, list[str]] = {}
    for p, n in zip(items, names, strict=True):
        out.setdefault(find(n), []).append(p)
    return sorted(out.values(), key=len, reverse=True)


# ----------------------------------------------------------------------- the worker's side


@dataclass
class IngestCall:
    """The arguments of one ``HealthStore.ingest_log`` call, as a worker's replay made it."""

    units: list
    periods: list
    alarms: list
    gap_s: float


class CaptureStore:
    """The store a task's replay sees: ``latest_baseline`` from the baselines the task
    carries, ``stream_ids`` from the stored streams it carries and those of the task's logs
    read so far (the replay looks for them inside each log, ``service.store.identity``),
    ``ingest_log`` captured (``calls``) for the client to write."""

    def __init__(
        self,
        where: str,
        baselines: dict[str, Any],
        streams: dict[str, dict[str, str]] | None = None,
    ) -> None:
        self.where = where
        self._baselines = baselines
        self._streams = streams or {}
        self._seen: dict[str, dict[str, Any]] = {}
        self.calls: list[IngestCall] = []

    def stream_ids(self, actuator: str) -> dict[str, Any]:
        """``{source: StreamId}`` of ``actuator``: the client's stored ones, then the task's."""
        from service.store.identity import StreamId

        out = {src: StreamId.loads(text) for src, text in self._streams.get(actuator, {}).items()}
        out.update(self._seen.get(actuator, {}))
        return out

    def latest_baseline(self, actuator: str) -> Any:
        """The client's store's latest baseline of ``actuator`` (None: not commissioned)."""
        return self._baselines.get(actuator)

    def ingest_log(self, units, periods, alarms, gap_s) -> dict[str, dict[str, Any]]:
        """Captured; the status and flight numbers come when the client writes it."""
        self.calls.append(IngestCall(list(units), list(periods), list(alarms), float(gap_s)))
        for u in units:
            if u.identity is not None:
                self._seen.setdefault(u.actuator, {})[u.source] = u.identity
        return {u.actuator: {"status": "new", "periods_new": 0, "flights": []} for u in units}

    def close(self) -> None:
        """Nothing to close."""


@dataclass
class GroupTask:
    """What travels to a worker: the group's logs (paths or URLs, in life order), the
    baselines of their actuators from the client's store, ``replay``'s settings and the
    per-log work function (pickled by name)."""

    logs: list[str]
    store: str
    baselines: dict[str, Any]
    gap_s: float
    kw: dict[str, Any]
    work: Callable[..., Any]  # service.replay.replay_many (passed in: no import back up)
    streams: dict[str, dict[str, str]] = field(default_factory=dict)  # stored StreamIds, dumped


@dataclass
class GroupResult:
    """A task's result: per log (log, summary or None, error or None, ingest call or None),
    in the group's order, and the worker that ran it."""

    logs: list[tuple[str, Any, str | None, IngestCall | None]]
    worker: str
    wall_s: float


def worker_name() -> str:
    """The Dask worker's address, else this host and process."""
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        import socket

        return f"{socket.gethostname()}:pid{os.getpid()}"


def run_group(task: GroupTask) -> GroupResult:
    """A worker's task: each log of the group through ``task.work`` (``replay_many``, one log
    at a time, so a log's failure is its own) on a ``CaptureStore``; nothing is written
    here."""
    import tempfile

    w0 = time.perf_counter()
    cap = CaptureStore(task.store, task.baselines, task.streams)
    out: list[tuple[str, Any, str | None, IngestCall | None]] = []
    with tempfile.TemporaryDirectory(prefix="servowatch-logs-") as cache:
        for item in task.logs:
            cap.calls.clear()
            try:
                p = fetch(item, cache)
            except Exception as e:  # not there, not readable: named by its URL
                cause = (str(e).strip().splitlines() or [""])[0] or type(e).__name__
                out.append((item, None, f"{item}: cannot read: {cause}", None))
                continue
            got: list = []
            task.work([p], cap, flight_gap_s=task.gap_s, on_log=lambda _p, s, e, got=got:
                        got.append((s, e)), **task.kw)  # fmt: skip
            s, e = got[0] if got else (None, RuntimeError("no result"))
            if s is not None and str(p) != item:
                s.log = item  # the URL, not the worker's cached copy
            err = None if e is None else str(e).replace(str(p), item)
            call = cap.calls[-1] if s is not None and cap.calls else None
            if call is not None:  # each unit's stream identity as the store's text, made
                # here: the client writes it as it comes (a 2 h log's is about 1.3 MB)
                call.units = [u._replace(identity=u.identity.dumps())
                              if u.identity is not None and not isinstance(u.identity, str)
                              else u for u in call.units]  # fmt: skip
            out.append((item, s, err, call))
    return GroupResult(out, worker_name(), time.perf_counter() - w0)


# ------------------------------------------------------------------------------- the pools


def _die_with_parent(parent: int) -> None:
    """A ``--jobs`` worker's initializer: it logs as the batch does, and dies with it (Linux: the kernel sends it
    SIGKILL when its parent dies, ``PR_SET_PDEATHSIG``; elsewhere a thread polls the parent
    and ends the worker when it is gone)."""
    import signal
    import sys
    import threading

    armed = False
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(1, signal.SIGKILL, 0, 0, 0) == 0  # PR_SET_PDEATHSIG = 1
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent:  # the parent died before the prctl took effect
        os._exit(1)
    from service.log.setup import inherit_logging

    inherit_logging()  # its log lines as the batch's
    if not armed:

        def watch() -> None:
            while os.getppid() == parent:
                time.sleep(0.5)
            os._exit(1)

        threading.Thread(target=watch, daemon=True, name="parent-watch").start()


class ProcessPool:
    """``--jobs N``: N spawned processes of this machine that die with the batch."""

    def __init__(self, jobs: int) -> None:
        self.jobs = jobs
        self._ex: Any = None

    def describe(self) -> str:
        return f"{self.jobs} local processes"

    def start(self, n_tasks: int) -> None:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        self._ex = ProcessPoolExecutor(
            max(1, min(self.jobs, n_tasks)), mp_context=mp.get_context("spawn"),
            initializer=_die_with_parent, initargs=(os.getpid(),),
        )  # fmt: skip

    def submit(self, fn: Callable, arg: Any) -> Any:
        return self._ex.submit(fn, arg)

    def as_completed(self, futures: list) -> Iterator:
        from concurrent.futures import as_completed

        return as_completed(futures)

    def stop(self) -> None:
        if self._ex is not None:
            self._ex.shutdown(wait=True, cancel_futures=True)
            self._ex = None

    def close(self) -> None:
        self.stop()


CONNECT_TIMEOUT_S = 10.0  # a scheduler that does not answer in this time is unreachable


def check_cluster(spec: str) -> int | None:
    """N of ``local:N``, None for a scheduler's address; ValueError (one line naming
    ``--cluster``) for anything else."""
    if spec.startswith("local:"):
        n = spec.removeprefix("local:")
        if not n.isdigit() or int(n) < 1:
            raise ValueError(f"--cluster {spec}: local:N takes a number of workers >= 1")
        return int(n)
    if not re.match(r"^[a-z][a-z0-9+.-]*://\S+$", spec):
        raise ValueError(f"--cluster {spec}: expected tcp://HOST:PORT (a Dask scheduler) or "
                         "local:N")  # fmt: skip
    return None


@contextmanager
def _quiet() -> Iterator[None]:
    """Dask's, Tornado's and asyncio's loggers at CRITICAL meanwhile."""
    quiet = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    levels = [q.level for q in quiet]
    for q in quiet:
        q.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for q, lv in zip(quiet, levels, strict=True):
            q.setLevel(lv)


_WORKER_LOGGING = False  # set in a Dask worker once its log lines follow the batch's


def _logging_as_the_batch(fn: Callable, arg: Any) -> Any:
    """``fn(arg)`` on a Dask worker, whose log lines follow the batch's format (a
    ``local:N`` worker inherits ``SERVOWATCH_CHILD_LOG``; another host's, plain text) rather
    than Python's bare last-resort lines."""
    global _WORKER_LOGGING
    if not _WORKER_LOGGING:
        from service.log.setup import inherit_logging

        inherit_logging()
        _WORKER_LOGGING = True
    return fn(arg)


class DaskPool:
    """``--cluster``: a Dask distributed scheduler at an address (``tcp://HOST:PORT``,
    ``tls://...``), or ``local:N``, a ``LocalCluster`` of N single-threaded worker processes
    on loopback (dashboard off). Connects in the constructor (``ClusterError``)."""

    def __init__(self, spec: str, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
        from distributed import Client

        n = check_cluster(spec)
        self.spec = spec
        self._cluster = None
        with _quiet():  # the connect's retries are logged at ERROR: one line is ours
            if n is not None:
                from distributed import LocalCluster

                self._cluster = LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                    dashboard_address=None, worker_dashboard_address=None, scheduler_port=0,
                    silence_logs=logging.ERROR,
                )  # fmt: skip
                self.client = Client(self._cluster, timeout=f"{timeout_s}s")
            else:
                try:
                    self.client = Client(spec, timeout=f"{timeout_s}s")
                except (OSError, TimeoutError, ValueError) as e:
                    text = (str(e).strip().splitlines() or [""])[0] or type(e).__name__
                    raise ClusterError(f"--cluster {spec}: no Dask scheduler reachable: "
                                       f"{text}") from None  # fmt: skip

    def describe(self) -> str:
        n = len(self.client.scheduler_info().get("workers", {}))
        return f"Dask scheduler {self.client.scheduler.address} with {n} worker(s)"

    def start(self, n_tasks: int) -> None:
        """Nothing to start: the workers are the scheduler's."""

    def submit(self, fn: Callable, arg: Any) -> Any:
        return self.client.submit(_logging_as_the_batch, fn, arg, pure=False)

    def as_completed(self, futures: list) -> Iterator:
        from distributed import as_completed

        return iter(as_completed(futures))

    def stop(self) -> None:
        """The cluster stays (``close`` leaves it)."""

    def close(self) -> None:
        with _quiet():  # a LocalCluster's shutdown is logged line by line
            self.client.close()
            if self._cluster is not None:
                self._cluster.close()


def open_pool(jobs: int = 1, cluster: str | None = None) -> ProcessPool | DaskPool:
    """The pool of a batch: ``cluster`` (``DaskPool``, connected now) or ``jobs``
    processes."""
    return DaskPool(cluster) if cluster else ProcessPool(jobs)


# ----------------------------------------------------------------------------- the client


@dataclass
class WorkerLoad:
    """What one worker did in a batch."""

    tasks: int = 0
    logs: int = 0
    failed: int = 0
    samples: int = 0
    busy_s: float = 0.0


@dataclass
class BatchReport:
    """The batch beyond the per-log summaries: the pool and each worker's load."""

    pool: str = ""
    workers: dict[str, WorkerLoad] = field(default_factory=dict)


def write_logs(hs: Any, done: list[tuple[Any, IngestCall]]) -> None:
    """The captured store writes of a task's logs (summary, call), done here in one
    transaction (``HealthStore.ingest_logs``: each unit renumbered once), and each summary's
    store fields from them (as ``service.replay.core._store_log`` sets them)."""
    from service.replay.input import StoreWriteError

    if not done:
        return
    try:
        res = hs.ingest_logs([(c.units, c.periods, c.alarms) for _, c in done], done[0][1].gap_s)
    except Exception as e:
        first = (str(e).strip().splitlines() or [""])[0] or type(e).__name__
        names = done[0][0].log + (f" and {len(done) - 1} more log(s)" if len(done) > 1 else "")
        raise StoreWriteError(
            f"store {getattr(hs, 'where', hs)}: writing {names} failed: {first}"
        ) from e
    from service.replay.stored import store_result

    for (s, _), r in zip(done, res, strict=True):
        store_result(s, r)


def run_batch(
    logs: list[str | Path],
    store: str | Path,
    pool: ProcessPool | DaskPool,
    *,
    on_log: Callable[[Any, Any, Exception | None], None] | None = None,
    tick: Callable[[], None] | None = None,
    flight_gap_s: float,
    kw: dict[str, Any],
    work: Callable[..., Any],
    report: BatchReport | None = None,
    task_logs: int | None = None,
) -> list:
    """``logs`` (paths or fsspec URLs) replayed by ``pool``'s workers with ``work``
    (``service.replay.replay_many``, run on one log at a time), one task per group
    (``groups``, each in life order), and written to ``store`` here as each task completes;
    ``tick`` as ``replay_many`` calls it, once per log of a completed task; ``on_log`` at
    once for a log that failed, at the end of the batch for the others, with the flights
    as the store numbers them then (a URL is passed as its text, a path as a ``Path``). A task whose workers
    all died (more often than the scheduler allows) names each of its logs as failed.
    ``report`` gets the pool and each worker's load. ``StoreWriteError``: the store failed
    (the logs written before it stay, each whole).

    ``task_logs``: a group is cut into tasks of at most this many consecutive logs, which
    may run at once: each log's replay starts its monitor afresh (``replay``) and only this
    client writes, in any order (the store is the same for any split and order of the
    logs, decision record 0010), so the batch is no longer as long as its largest group."""
    from service.replay.input import LogError, StoreWriteError
    from service.store import open_store

    report = report if report is not None else BatchReport()
    written: list[tuple[Any, Any]] = []  # on_log after the batch: the final flights
    report.pool = pool.describe()
    items = [str(p) for p in logs]
    pool.start(len(items))
    try:
        if all(local_path(i) is not None for i in items):
            facts = {i: log_facts(i) for i in items}
        else:  # read where the logs are readable: on the workers
            futs = [pool.submit(log_facts, i) for i in items]
            facts = {i: f.result() for i, f in zip(items, futs, strict=True)}
        items.sort(key=lambda i: facts[i].order)
        out: list = []
        with open_store(store) as hs:
            tasks = []
            rank: list[tuple[int, int]] = []  # each task's group and place in it
            k = task_logs or len(items)
            for g, gi, i in (
                (grp[i : i + k], gi, i // k)
                for gi, grp in enumerate(groups(items, facts))
                for i in range(0, len(grp), k)
            ):
                rank.append((gi, i))
                acts = sorted({a for i in g for a in facts[i].units if not a.startswith("?")})
                bl = {a: rec for a in acts if (rec := hs.latest_baseline(a)) is not None}
                streams = {a: {src: sid.dumps() for src, sid in hs.stream_ids(a).items()}
                           for a in acts}  # fmt: skip
                tasks.append(GroupTask(g, str(store), bl, flight_gap_s, kw, work, streams))
            futs = [pool.submit(run_group, t) for t in tasks]
            by_fut = {id(f): t for f, t in zip(futs, tasks, strict=True)}
            for f in in_group_order(pool.as_completed(futs), futs, rank):
                t = by_fut[id(f)]
                try:
                    res: GroupResult = f.result()
                except Exception as exc:  # its workers died (killed, out of memory)
                    why = f"worker failed: {type(exc).__name__} {exc}".strip()
                    res = GroupResult([(p, None, f"{p}: {why}", None) for p in t.logs],
                                      "(lost)", 0.0)  # fmt: skip
                load = report.workers.setdefault(res.worker, WorkerLoad())
                load.tasks += 1
                load.busy_s += res.wall_s
                try:
                    write_logs(hs, [(s, c) for _, s, _, c in res.logs if s is not None and c])
                except StoreWriteError:
                    for key, s in written:  # the logs stored before it
                        if on_log is not None:
                            on_log(key, s, None)
                    raise
                for item, s, err, _ in res.logs:
                    load.logs += 1
                    key = item if is_url(item) else Path(item)
                    if s is not None:
                        load.samples += s.samples
                        out.append(s)
                        written.append((key, s))
                    else:
                        load.failed += 1
                        if on_log is not None:
                            on_log(key, None, LogError(err or "failed"))
                    if tick is not None:
                        tick()
            final_flights(hs, out)
    finally:
        pool.stop()
    for key, s in written:
        if on_log is not None:
            on_log(key, s, None)
    return out


def in_group_order(
    done: Iterable[Any], futs: list[Any], rank: list[tuple[int, int]]
) -> Iterator[Any]:
    """The futures ``done`` yields as they complete, each group's tasks in their order
    (``rank``: each future's group and place in it): a task that completes before an
    earlier one of its group waits for it, its result where it is (on its Dask worker)
    until then. So a group's logs reach the store in life order and each unit's periods
    follow its stored ones: the store's incremental renumbering, no read of the unit's
    history (``service.store.renumber``, decision record 0044)."""
    at = {id(f): r for f, r in zip(futs, rank, strict=True)}
    waiting: dict[tuple[int, int], Any] = {}
    nxt: dict[int, int] = {}
    for f in done:
        g, k = at[id(f)]
        waiting[(g, k)] = f
        while (g, nxt.get(g, 0)) in waiting:
            yield waiting.pop((g, nxt.get(g, 0)))
            nxt[g] = nxt.get(g, 0) + 1


def final_flights(hs: Any, summaries: list) -> None:
    """Each summary's ``flights`` as the store numbers them at the end of the batch (a log
    written before an earlier one of its unit had its gap-rule flights renumbered since)."""
    acts = sorted({a for s in summaries for a in s.flights})
    for a in acts:
        by_src: dict[str, set[int]] = {}
        for p in hs.periods(a):
            if p.flight is not None:
                by_src.setdefault(p.source, set()).add(int(p.flight))
        for s in summaries:
            if a in s.flights and a in s.sources:
                s.flights[a] = sorted(by_src.get(s.sources[a], ()))
