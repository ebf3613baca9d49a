"""``replay --jobs N``: a batch split into groups of logs that share no actuator, each in a
worker process that dies with the command (``_die_with_parent``)."""

from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Any

from service.log import rotated_files
from service.replay.input import LogError, StoreWriteError, check_mcap

__all__ = ["replay_parallel"]


def _groups(logs: list[Path]) -> list[list[Path]]:
    """``logs`` split into groups that share no actuator (by the logs' meas topics), each in
    the given order (a file that is not a readable log: a group of its own)."""
    from service.log.flightrec import log_units

    parent: dict[str, str] = {}

    def find(a: str) -> str:
        while parent.setdefault(a, a) != a:
            a = parent[a]
        return a

    names = []
    for p in logs:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                check_mcap(rotated_files(p)[0])
                units = log_units(rotated_files(p)[0])
        except Exception:  # not a log: it fails in its worker, alone
            units = [f"?{p}"]
        units = units or ["?"]  # a log without a unit: one group for all of them
        for u in units[1:]:
            parent[find(u)] = find(units[0])
        names.append(units[0])
    groups: dict[str, list[Path]] = {}
    for p, n in zip(logs, names, strict=True):
        groups.setdefault(find(n), []).append(p)
    return sorted(groups.values(), key=len, reverse=True)


_TICKS: Any = None  # a worker's progress queue (set by _die_with_parent)


def _die_with_parent(parent: int, ticks: Any) -> None:
    """A ``--jobs`` worker's initializer: it dies with the batch (Linux: the kernel sends it
    SIGKILL when its parent dies, ``PR_SET_PDEATHSIG``; elsewhere a thread polls the parent
    and ends the worker when it is gone)."""
    import os
    import signal
    import sys
    import threading

    global _TICKS
    _TICKS = ticks
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
    if not armed:

        def watch() -> None:
            while os.getppid() == parent:
                time.sleep(0.5)
            os._exit(1)

        threading.Thread(target=watch, daemon=True, name="parent-watch").start()


def _group_job(args) -> tuple[list[tuple[str, dict | None, str | None]], str | None]:
    """A worker's group: each log's (path, summary dict, error) and the store's failure."""
    logs, store, gap, kw, replay_many = args
    out = []

    def on_log(p, s, e) -> None:
        out.append((str(p), None if s is None else s.to_dict(), None if e is None else str(e)))

    try:
        replay_many(logs, store, on_log=on_log, flight_gap_s=gap, tick=lambda: _TICKS.put(1),
                    **kw)  # fmt: skip
    except StoreWriteError as e:
        return out, str(e)
    return out, None


def replay_parallel(logs, store, on_log, tick, gap, jobs, kw, replay_many, summary) -> list:
    """``service.replay.replay_many`` with ``jobs`` > 1 (its docstring); ``replay_many`` and
    ``summary`` (``ReplaySummary``) are passed in, the workers run the former."""
    import multiprocessing as mp
    import os
    import queue
    from concurrent.futures import ProcessPoolExecutor, wait

    from service.store import open_store

    open_store(store).close()  # migrate once, before the workers open it
    groups = _groups(logs)
    ctx = mp.get_context("spawn")
    ticks = ctx.Queue()
    n = min(jobs, len(groups))
    try:
        with ProcessPoolExecutor(n, mp_context=ctx, initializer=_die_with_parent,
                                 initargs=(os.getpid(), ticks)) as ex:  # fmt: skip
            futs = [ex.submit(_group_job, (g, str(store), gap, kw, replay_many)) for g in groups]
            pending = set(futs)
            while pending:
                _, pending = wait(pending, timeout=0.2)
                try:
                    while True:
                        ticks.get_nowait()
                        if tick is not None:
                            tick()
                except queue.Empty:
                    pass
            results: list = []
            store_err: str | None = None
            for g, f in zip(groups, futs, strict=True):
                try:
                    res, failed = f.result()
                except Exception as exc:  # a worker died (killed, out of memory)
                    why = f"worker process failed: {type(exc).__name__} {exc}".strip()
                    res, failed = [(str(p), None, f"{p}: {why}") for p in g], None
                results.extend(res)
                store_err = store_err or failed
    finally:
        ticks.close()
        ticks.join_thread()
    out = []
    for p, d, err in results:
        s = summary(**d) if d is not None else None
        if s is not None:
            out.append(s)
        if on_log is not None:
            on_log(Path(p), s, None if err is None else LogError(err))
    if store_err is not None:
        raise StoreWriteError(store_err)
    return out
