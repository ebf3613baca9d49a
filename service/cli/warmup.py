"""Compile and cache the numba kernels ahead of use (``servowatch warmup``,
``python -m service.cli.warmup``).

``make`` runs this right after installing, so the first ``servowatch demo`` or test run does
not spend its first minutes compiling; a pip-installed copy runs ``servowatch warmup`` once.
Safe to run any time: it only exercises the kernels (loaded from numba's cache when they are
compiled already). ``--table`` prints what each kernel cost: the compile seconds of every
numba function (its own, without the functions it calls, and in total).

The kernels are grouped by the command that needs them (``GROUPS``); a command that would
compile a group first says so on stderr (:func:`announce`).
"""

from __future__ import annotations

import io
import json
import logging
import os
import subprocess
import sys
import time
from collections.abc import Callable

__all__ = [
    "warm_up",
    "GROUPS",
    "DEFAULT_GROUPS",
    "ensure",
    "monitor_group",
    "is_cached",
    "table",
    "print_table",
]

_logger = logging.getLogger("servowatch.warmup")


def _models() -> None:
    """The HF bench: the virtual actuator (``servowatch actuator``, the demo), calibrate,
    estimate."""
    from models.eha import EHAStepper
    from models.params import EHAParams

    st = EHAStepper(EHAParams(), "HF")
    for _ in range(3):
        st.advance(10, 0.001, 0.0, 20e6, 2e-13)


def _valves() -> None:
    """The bench on every other valve model (A, B, C1, C3, C5, WH): simulate, compare."""
    from models.eha import VALVE_MODELS, simulate
    from models.scenario import Scenario

    sc = Scenario(name="warmup", duration_s=2e-3, step_s=1e-4)
    for valve in VALVE_MODELS:
        simulate(sc, valve)


def _monitor_run(model: str) -> None:
    import numpy as np

    from models.eha import EHAStepper
    from models.params import EHAParams
    from service.monitor import Monitor, MonitorBank, MonitorConfig
    from service.wire.messages import decode_into, decode_meas_arrays, encode_meas

    cfg = MonitorConfig(model=model)
    st = EHAStepper(EHAParams(), "HF")
    samples = []
    for k in range(20):
        st.advance(10, 0.001, 0.0, 20e6, 2e-13)
        samples.append({**st.signals(), "t": 1e-3 * k})
    mon = Monitor(cfg)
    for s in samples:
        mon.update(s)
    bank = MonitorBank(cfg)
    bank.update_rows([("a", s) for s in samples[:1]])
    for s in samples[1:]:
        bank.update_rows([("a", s)])
    payload = encode_meas([{**s, "seq": k} for k, s in enumerate(samples)])
    arr = decode_meas_arrays(payload)
    decode_into([payload], np.empty(20, np.int64), np.empty(20), np.empty((20, 7)))  # the intake's
    bank.update_arrays([bank.index_of("b")] * len(arr.t), arr.t, arr.values)


def _monitor() -> None:
    """The degradation monitor (one set of kernels for every process model: WH, the default,
    and the C-type laws): run, replay, estimate, calibrate."""
    _monitor_run("WH")
    _monitor_run("C5")


def _ukf_step(model: str) -> None:
    """One UKF step of ``model``'s process model, called directly with the argument types of
    the monitor's ``step_one`` (plain C-contiguous arrays, a run-time flag): compiled in a
    process of its own beside the rest of the monitor, which then loads it from the cache."""
    import numpy as np

    from service.monitor import MonitorBank, MonitorConfig
    from service.monitor.ukf import merwe_weights, ukf_one, ukf_one_wh, workspace

    bank = MonitorBank(MonitorConfig(model=model))
    n, m = len(bank.scale), len(bank._zscale)
    w = merwe_weights(n, 0.5)
    step = ukf_one_wh if model == "WH" else ukf_one
    step(np.zeros(n), np.eye(n), np.zeros(m), np.ones(m, np.bool_), 0.0, 1e-3, 1, bank._q,
         np.ascontiguousarray(bank.R), bank.scale, bank._zscale, w.Wm, w.Wc, w.c, bank._prm,
         np.zeros(m), workspace(n, m), False)  # fmt: skip


def _trend() -> None:
    """The RUL's opt-in trend model (``rul --robust-trend``): its Kalman filter and smoother,
    called as the Student-t scales' EM and the fit call it."""
    import numpy as np

    from service.prognostics.trend import fit_trend, scale_weights

    u = np.linspace(0.05, 1.0, 8)
    y = 1.0 + 2.0 * u
    m0, sd0 = np.array([1.0, 0.0]), np.array([0.3, 8.0])
    scale_weights(u, y, 0.03, m0, sd0)
    fit_trend(u, y, np.full(8, 1e-3), None, m0, sd0)


def _log() -> None:
    """The MCAP log's reader (chunk scan, JSON messages): replay, and the older logs."""
    from service.log import codec as logcodec

    logcodec.warm_up()


GROUPS: dict[str, Callable[[], None]] = {
    "models": _models,
    "monitor": _monitor,
    "log": _log,
    "valves": _valves,
    "trend": _trend,
}
# what `servowatch warmup` compiles by default: what the demo, the daemon, the replay and the
# virtual actuator need; the other groups compile on their first use (announced) or --all
# (trend: the RUL's opt-in trend model, about 2 CPU s, on the first `rul --robust-trend`)
DEFAULT_GROUPS = ("models", "monitor", "log")

# A cold warm-up runs in parts, each in a process of its own, on as many cores as there are
# (``jobs``): the two UKF steps, the monitor's largest kernels, compile beside each other and
# beside the log's kernels; the rest of the monitor waits for them and for the HF bench.
# part: (warm-up, the parts it waits for when they run too, CPU seconds of its compile: the
# ready part on the longest chain starts first)
PARTS: dict[str, tuple[Callable[[], None], tuple[str, ...], float]] = {
    "ukf_wh": (lambda: _ukf_step("WH"), (), 30.0),
    "ukf_c": (lambda: _ukf_step("C5"), (), 20.0),
    "monitor": (_monitor, ("ukf_wh", "ukf_c", "models"), 25.0),
    "log": (_log, (), 20.0),
    "valves": (_valves, (), 15.0),
    "models": (_models, (), 5.0),
    "trend": (_trend, (), 2.0),
}
GROUP_PARTS = {
    "models": ("models",),
    "monitor": ("ukf_wh", "ukf_c", "monitor"),
    "log": ("log",),
    "valves": ("valves",),
    "trend": ("trend",),
}

WHAT = {
    "models": "the HF bench kernels",
    "valves": "the simplified valve models' bench kernels",
    "monitor": "the monitor kernels",
    "log": "the MCAP log kernels",
    "trend": "the RUL's trend model kernel",
}
# CPU seconds of each group's first compile on this project's 2-core VM, with the start-up
# of its processes (`time servowatch warmup --group G` from a cold cache); a compiling
# command prints their sum over the cores it uses (at most 2: the parts wait for each other)
ESTIMATE_S = {"models": 10.0, "monitor": 60.0, "log": 25.0, "valves": 20.0, "trend": 5.0}


# the kernels each group's warm-up calls from Python (numba's cache of these tells whether
# the group would compile)
def _entries(group: str) -> list:
    if group == "models":
        from models import compiled

        return [compiled._integrate_hf]
    if group == "valves":
        from models import compiled

        return list(compiled._LOOPS[1:])
    if group == "trend":
        from service.prognostics import trend

        return [trend._kalman]
    if group == "monitor":
        from models import compiled
        from service.monitor import kernels, usage
        from service.wire import kernels as wire_kernels

        return [compiled._integrate_hf, kernels.bank_step, kernels.output_rows, kernels.block_steps,
                kernels.block_rows, kernels.prepare_inputs, usage.usage_rows,
                wire_kernels.decode_message, wire_kernels.intake_batch]  # fmt: skip
    from service.log import codec_read

    return [codec_read._scan, codec_read._fill, codec_read._objects]


def _part_entries(part: str) -> list:
    if part in ("ukf_wh", "ukf_c"):
        from service.monitor import ukf

        return [ukf.ukf_one_wh if part == "ukf_wh" else ukf.ukf_one]
    return _entries(part)


def default_jobs() -> int:
    """Processes of a cold warm-up: one per core, at most 4."""
    return max(1, min(os.cpu_count() or 1, 4))


def _parts_of(groups: tuple[str, ...], cold_only: bool) -> list[str]:
    """The parts of ``groups`` (the callers pass the groups numba's cache lacks);
    ``cold_only``: those whose own kernels it lacks."""
    return [p for g in groups for p in GROUP_PARTS[g] if not (cold_only and _part_cached(p))]


def _part_cached(part: str) -> bool:
    """True when numba's cache holds the kernels that ``part`` calls from Python."""
    from service.compat.numba import has_cached_code

    return all(has_cached_code(d) for d in _part_entries(part))


def _run_part(part: str, record: bool, t0: float, stream, log: bool = False) -> list[tuple]:
    """Run one part here, announcing each kernel it compiles on ``stream`` (the seconds since
    ``t0``, a wall clock), or as a log line of ``servowatch.warmup`` (``log``: a service's
    start); ``record``: return its compile rows (group, kernel, signatures, own s, total s)."""
    from numba.core import event

    rec = _CompileTimes()
    depth = [0]
    seen = _SeenKernels(os.environ.get("SERVOWATCH_WARMUP_SEEN"))

    def on_start(ev) -> None:
        depth[0] += 1
        rec.on_start(ev)

    def on_end(ev) -> None:
        depth[0] -= 1
        rec.on_end(ev)
        if depth[0] == 0 and (stream is not None or log):
            f = ev.data["dispatcher"].py_func
            name = f"{f.__module__}.{f.__qualname__}"
            if not seen.first(name):  # once per kernel: another signature, another part: silent
                return
            if log:
                dt = time.time() - t0
                _logger.info("compiled %s (%.0f s)", name, dt,
                          extra={"fields": {"kernel": name, "elapsed_s": round(dt, 1)}})  # fmt: skip
            else:
                print(f"servowatch:   compiled {name} ({time.time() - t0:.0f} s)", file=stream,
                      flush=True)  # fmt: skip

    with event.install_listener("numba:compile", _listener(on_start, on_end)):
        PARTS[part][0]()
    group = next(g for g, ps in GROUP_PARTS.items() if part in ps)
    return [(group, k, rec.count[k], rec.own[k], rec.total[k]) for k in rec.own] if record else []


_ANNOUNCED: set[str] = set()  # kernels announced by the parts run in this process


class _SeenKernels:
    """The kernels announced so far by the parts of one warm-up: a marker file per kernel in
    ``folder`` (shared by the parts' processes, created exclusively), else this process's
    set. A kernel compiled for a second signature, or by two parts, is announced once."""

    def __init__(self, folder: str | None) -> None:
        self.folder = folder
        self.names: set[str] = set() if folder else _ANNOUNCED  # in process: every part's

    def first(self, name: str) -> bool:
        if name in self.names:
            return False
        self.names.add(name)
        if not self.folder:
            return True
        try:
            fd = os.open(os.path.join(self.folder, name), os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            return False
        except OSError:  # the folder is gone: announce rather than hide
            return True
        os.close(fd)
        return True


def _path_s(part: str, parts: list[str]) -> float:
    """CPU seconds from the start of ``part`` to the end of the longest chain of ``parts``
    that waits for it (the critical path first: a small part that the monitor waits for
    starts before a larger one that nothing waits for)."""
    after = [_path_s(q, parts) for q in parts if part in PARTS[q][1]]
    return PARTS[part][2] + max(after, default=0.0)


def run_parts(
    parts: list[str],
    jobs: int | None = None,
    record: bool = False,
    stream=None,
    log: bool = False,
) -> tuple[list[tuple], float]:
    """Run the warm-up ``parts``: in this process when ``jobs`` is 1 or there is one part,
    else each in a process of its own, ``jobs`` at a time, a part starting once the parts it
    waits for have ended (the longest first). Compiles are announced on ``stream``, or as
    log lines in the process's log format (``log``; a part's process inherits it). Returns
    the compile rows (``record``) and the wall time [s]."""
    t0 = time.time()
    jobs = default_jobs() if jobs is None else max(1, jobs)
    rows: list[tuple] = []
    if jobs == 1 or len(parts) <= 1:
        for p in parts:
            rows += _run_part(p, record, t0, stream, log)
        return rows, time.time() - t0
    import tempfile

    seen = tempfile.TemporaryDirectory(prefix="servowatch-warmup-")
    env = {**os.environ, "SERVOWATCH_WARMUP_T0": repr(t0), "SERVOWATCH_WARMUP_SEEN": seen.name}
    if log:  # the parts log their lines as this process does, straight to its stderr
        env["SERVOWATCH_WARMUP_LOG"] = "1"
        stream = sys.stderr
    try:  # a file stream takes the parts' lines as they come; another one, when they end
        err = stream.fileno() if stream is not None else subprocess.DEVNULL
    except (AttributeError, OSError, ValueError):
        err = subprocess.PIPE
    todo, running = list(parts), {}
    while todo or running:
        ready = [p for p in todo if not any(d in todo or d in running for d in PARTS[p][1])]
        for p in sorted(ready, key=lambda q: -_path_s(q, parts))[: jobs - len(running)]:
            cmd = [sys.executable, "-m", "service.cli.warmup", "--part", p]
            running[p] = subprocess.Popen(
                cmd + (["--record"] if record else []), env=env, text=True,
                stdout=subprocess.PIPE, stderr=err,
            )  # fmt: skip
            todo.remove(p)
        for p, proc in list(running.items()):
            if proc.poll() is None:
                continue
            out, lines = proc.communicate()
            if lines:
                stream.write(lines)
            del running[p]
            if proc.returncode != 0:
                for q in running.values():
                    q.kill()
                raise RuntimeError(f"warm-up part {p!r} failed (exit {proc.returncode})")
            if record and out.strip():
                rows += [tuple(r) for r in json.loads(out)]
        time.sleep(0.05)
    return rows, time.time() - t0


def warm_up(groups: tuple[str, ...] | None = None, jobs: int | None = None) -> float:
    """Run every compiled path (or those of ``groups``) briefly, the cold ones on ``jobs``
    processes: :func:`ensure` with ``always``, its messages discarded. Returns the wall
    time [s]."""
    groups = DEFAULT_GROUPS if groups is None else groups
    return ensure(*groups, always=True, stream=io.StringIO(), jobs=jobs)


class _CompileTimes:
    """Compile seconds per numba function, from numba's ``numba:compile`` events (a cache
    load is not a compile event). Own time excludes the functions compiled while it compiled
    (its callees); total includes them."""

    def __init__(self) -> None:
        self.stack: list[list] = []  # [name, t_start, child_seconds]
        self.own: dict[str, float] = {}
        self.total: dict[str, float] = {}
        self.count: dict[str, int] = {}

    def on_start(self, ev) -> None:
        d = ev.data["dispatcher"]
        name = f"{d.py_func.__module__}.{d.py_func.__qualname__}"
        self.stack.append([name, time.perf_counter(), 0.0])

    def on_end(self, ev) -> None:
        name, t0, child = self.stack.pop()
        dt = time.perf_counter() - t0
        if self.stack:
            self.stack[-1][2] += dt
        self.own[name] = self.own.get(name, 0.0) + dt - child
        self.total[name] = self.total.get(name, 0.0) + dt
        self.count[name] = self.count.get(name, 0) + 1


def _listener(on_start: Callable, on_end: Callable):
    """A numba event listener calling ``on_start`` / ``on_end`` with each event."""
    from numba.core import event

    class _L(event.Listener):
        def on_start(self, ev) -> None:
            on_start(ev)

        def on_end(self, ev) -> None:
            on_end(ev)

    return _L()


def table(
    groups: tuple[str, ...] | None = None, jobs: int | None = None
) -> tuple[list[tuple[str, str, int, float, float]], float]:
    """Warm up with numba's compile events recorded: rows (group, kernel, signatures, own s,
    total s), slowest first, and the wall time (the cold parts on ``jobs`` processes)."""
    groups = DEFAULT_GROUPS if groups is None else groups
    rows, wall = run_parts(_parts_of(groups, cold_only=False), jobs, record=True)
    rows.sort(key=lambda r: -r[3])
    return rows, wall


def is_cached(group: str) -> bool:
    """True when the entry kernels of ``group`` have compiled code in numba's cache for their
    current source (their first call loads it; no compile). Reads the cache index only."""
    from service.compat.numba import has_cached_code

    return all(has_cached_code(d) for d in _entries(group))


def monitor_group(model: str) -> str:
    """The warm-up group of the monitor on process ``model`` (a MonitorConfig.model): one
    set of kernels serves every process model."""
    return "monitor"


def estimate_text(cold: list[str], jobs: int | None = None, load: float | None = None) -> str:
    """What a cold compile of ``cold`` will take and what the figure assumes: the CPU seconds
    measured on this project's 2-core VM (``ESTIMATE_S``) over the cores it uses, if they are
    idle; the load average now (``load``: os.getloadavg's), which lengthens it."""
    n = default_jobs() if jobs is None else max(1, jobs)
    used = min(n, 2)  # the parts wait for each other: at most 2 run at once
    cpu = sum(ESTIMATE_S[g] for g in cold)
    if load is None:
        try:
            load = os.getloadavg()[0]
        except OSError:
            load = None
    text = (
        f"first run, about {cpu / used:.0f} s if {used} core{'s are' if used > 1 else ' is'} "
        f"idle: {cpu:.0f} s of CPU measured on a 2-core VM"
    )
    if load is not None:
        cores = os.cpu_count() or 1
        busy = f", more now: load average {load:.1f} on {cores} cores" if load > 0.5 * cores else ""
        text += busy
    return text + "; cached afterwards; `servowatch warmup` does it ahead"


def ensure(
    *groups: str, always: bool = False, stream=None, jobs: int | None = None, log: bool = False
) -> float:
    """Compile the kernels of ``groups`` that numba's cache lacks, before a command uses
    them, saying so on ``stream`` (stderr), or as log lines of ``servowatch.warmup`` (``log``:
    a service, whose lines are all in its log format): what, an estimate, then a line per
    kernel as it is compiled, on ``jobs`` processes. Silent and cheap when they are cached
    (``always``: run the warm-up anyway, loading from the cache). Returns the wall time [s]."""
    out = sys.stderr if stream is None else stream
    t0 = time.perf_counter()
    cold = [g for g in groups if not is_cached(g)]
    if cold:
        what = ", ".join(WHAT[g] for g in cold)
        if log:
            _logger.info("compiling %s (%s)", what, estimate_text(cold, jobs),
                      extra={"fields": {"groups": cold}})  # fmt: skip
        else:
            print(f"servowatch: compiling {what} ({estimate_text(cold, jobs)})...", file=out,
                  flush=True)  # fmt: skip
        # a part's lines go straight to a file stream; another stream gets them from here
        run_parts(_parts_of(tuple(cold), cold_only=True), jobs, stream=out, log=log)
    if always:  # the cached groups exercised here (the cold ones ran in their parts)
        for g in groups:
            if g not in cold:
                GROUPS[g]()
    if cold and log:
        dt = time.perf_counter() - t0
        _logger.info(
            "kernels compiled in %.0f s", dt, extra={"fields": {"elapsed_s": round(dt, 1)}}
        )
    elif cold:
        print(f"servowatch: kernels compiled in {time.perf_counter() - t0:.0f} s", file=out,
              flush=True)  # fmt: skip
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(
        prog="python -m service.cli.warmup", description=__doc__.split("\n")[0]
    )
    ap.add_argument("--table", action="store_true", help="print the compile seconds per kernel")
    ap.add_argument("--group", action="append", choices=tuple(GROUPS), default=None,
                    help="only this group of kernels (repeatable; default: models, monitor, "
                    "log; valves: compiled on first use)")  # fmt: skip
    ap.add_argument("--jobs", type=int, default=None, help="processes of a cold warm-up "
                    "(default: one per core, at most 4)")  # fmt: skip
    ap.add_argument("--part", choices=tuple(PARTS), help=argparse.SUPPRESS)
    ap.add_argument("--record", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.part:  # one part of a parallel warm-up (run_parts)
        t0 = float(os.environ.get("SERVOWATCH_WARMUP_T0", time.time()))
        log = os.environ.get("SERVOWATCH_WARMUP_LOG") == "1"
        if log:  # a service's start: its log format (service.log.setup)
            from service.log.setup import inherit_logging

            inherit_logging()
        rows = _run_part(a.part, a.record, t0, sys.stderr, log)
        if a.record:
            print(json.dumps(rows))
        return 0
    groups = tuple(a.group) if a.group else None
    if not a.table:
        dt = warm_up(groups, a.jobs)
        print(f"servowatch: compiled kernels ready ({dt:.1f} s)", file=sys.stderr)
        return 0
    rows, wall = table(groups, a.jobs)
    print_table(rows, wall)
    return 0


def print_table(rows: list[tuple[str, str, int, float, float]], wall: float) -> None:
    """The rows of :func:`table` as text, slowest first, with their sum and the wall time."""
    print(f"{'group':<8} {'kernel':<60} {'sigs':>4} {'own_s':>7} {'total_s':>8}")
    for g, k, n, own, tot in rows:
        print(f"{g:<8} {k:<60} {n:>4} {own:7.2f} {tot:8.2f}")
    print(f"{'':<8} {'sum of own compile seconds':<60} {'':>4} {sum(r[3] for r in rows):7.2f}")
    print(f"wall {wall:.1f} s (compiles, and the warm-up runs themselves)", flush=True)


if __name__ == "__main__":
    sys.exit(main())
