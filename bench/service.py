"""Benchmark: does the monitoring daemon keep up with N actuators at R Hz, with no drop?

Three processes on loopback (a Zenoh router in this process):

* a load generator (child process) publishing pre-computed samples of the virtual actuator
  (``scenarios/demo.toml``, HF bench with sensor noise), ``--spm`` samples per message,
  paced by the wall clock, bounded in count and time: one HF run encoded once (binary
  ``meas``), which every generator actuator sends on its own key; its reported CPU is the
  sending loop's (``cpu_setup_s``: the HF run and the encoding, before the sample clock
  starts);
* the daemon (child process): ``service.daemon.Daemon`` exactly as ``servowatch run`` builds
  it, with the real ``MonitorBank`` (``--monitor real``) or a no-op monitor (``--monitor
  null``, which isolates the transport, validation, MCAP logging and bookkeeping);
* this process: router, orchestration, table.

Reported per run: samples sent, received, processed, dropped (queue) and bad; the daemon's
sample-receipt -> health-output latency p50/p99; the sample-time -> health age p50/p99 (it
includes the publisher's batching); the worker's busy fraction; how long after the generator
stopped the daemon needed to finish its queue ("drain"). "keeps up" = nothing dropped, every
sample processed, the drain shorter than 1 s and the latency p99 under 1 s. ``--models``
runs the daemon's monitor on each process model in turn (default: the code's default);
``--compare-tree PATH`` runs every row again with the daemon of the checkout at PATH (its
``service`` package; the same load generator and orchestration), printed side by side. Latencies are
over the daemon's last 50 000 outputs (steady state on long runs).

    .venv/bin/python bench/service.py                       # default table
    .venv/bin/python bench/service.py --actuators 60 --monitor real --models WH,C5 \
        --compare-tree /tmp/base       # the same rows on another checkout's daemon, e.g.
                                       # git worktree add /tmp/base 85cd590
    .venv/bin/python bench/service.py --actuators 20 --rate 1000 --duration 10 --monitor null

``--viewer-cost``: the cost of serving Foxglove (``[foxglove]``, docs/dashboard.md), in one
run: the same load without the Foxglove server, then with a viewer (a WebSocket client in
this process, tests/_foxglove_ws.py) subscribed to the shipped layout's topics of one
actuator, then to every channel of every actuator (both at the default ``every`` = 10: one
row in 10 per topic), then the layout viewer with ``every`` = 1 (every row). The figure is the daemon process's CPU
time per sample (all its threads: worker, feeder, the SDK's server; the MCAP log process
is apart and does not change): throughput on a saturated CPU is its inverse, so
``cost = 1 - cpu_without / cpu_with`` is the fraction of throughput a viewer takes.

    .venv/bin/python bench/service.py --viewer-cost --actuators 10 --duration 10 --repeat 3

``--metrics-cost``: the cost of the OpenMetrics endpoint (``--metrics``, ``[metrics]``,
docs/dashboard.md, "Prometheus"), the same way: the same load without the endpoint, then
with it and a scraper in this process (``GET /metrics`` every second: 15 times Prometheus's
default rate), alternating run by run. Also reported: the scrape's own time (median, max).

    .venv/bin/python bench/service.py --metrics-cost --actuators 10 --duration 10 --repeat 3

``--metrics-load N``: scrapers cannot starve the monitor (issue 50): the health latency
(receipt of a sample to its health output, p99) of the same load without the endpoint's
scrapers, then with N scrapers in a process of their own, each a ``GET /metrics`` loop
without pause (answers 200 or, beyond the endpoint's cap, 503), alternating run by run. The
target: the p99 with 50 scrapers against 100 units within 2x of its value without them.

    .venv/bin/python bench/service.py --metrics-load 50 --actuators 100 --rate 100 --duration 10 --repeat 2
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


# --------------------------------------------------------------------------- CPU split

_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _stat_cpu(path: str) -> tuple[str, float]:
    """(comm, user + system CPU seconds) of a /proc/.../stat file."""
    with open(path) as f:
        txt = f.read()
    comm = txt[txt.index("(") + 1 : txt.rindex(")")]
    fields = txt[txt.rindex(")") + 2 :].split()
    return comm, (int(fields[11]) + int(fields[12])) / _TICK


def _threads_cpu(pid: int) -> dict[int, tuple[str, float]]:
    """Thread id -> (name, CPU seconds) of every thread of ``pid`` (Linux /proc)."""
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        with contextlib.suppress(OSError, ValueError):  # a thread that ended meanwhile
            out[int(tid)] = _stat_cpu(f"/proc/{pid}/task/{tid}/stat")
    return out


def _cpu_split(before: dict, after: dict, worker: int | None) -> dict[str, float]:
    """CPU seconds per thread group between two ``_threads_cpu`` snapshots: the worker
    thread; the monitor's step threads (``monitor-step_*``); the intake, Zenoh's calls into
    Python (``pyo3-closure`` threads: the subscriber callbacks); Zenoh's own threads (tokio
    runtimes: ``rx-``, ``tx-``, ``net-``, ...; every thread not started by Python); the
    rest (main thread, timers)."""
    import threading

    py = {t.native_id: t.name for t in threading.enumerate()}
    split: dict[str, float] = {}
    for tid, (name, cpu) in after.items():
        d = cpu - before.get(tid, (name, 0.0))[1]
        pname = py.get(tid)
        if tid == worker:
            group = "worker"
        elif pname is None:
            group = "zenoh"
        elif pname.startswith("monitor-step"):
            group = "monitor steps"
        elif "pyo3" in pname:
            group = "intake callbacks"
        else:
            group = "other"
        split[group] = split.get(group, 0.0) + d
    return split


# --------------------------------------------------------------------------- children


def _payloads(base: list[dict], n_actuators: int, spm: int, rate: float, t_start: float):
    """The messages of every generator actuator, pre-encoded (binary ``meas``, as
    ``messages.encode_meas`` makes them): actuator a's sample k is ``base[k]`` with seq k and
    t = t_start + k / rate, ``spm`` samples per message. Returns [(due offset s, [(actuator,
    payload), ...])], one entry per due time, in time order."""
    import numpy as np

    from service.wire import messages as m

    n = len(base)
    rec = np.zeros(n, [("seq", "<i8"), ("t", "<f8"), ("mask", "u1"), ("v", "<f8", (7,))])
    present = np.array([[base[k].get(c) is not None for c in m.CHANNELS] for k in range(n)])
    rec["mask"] = (present * (1 << np.arange(len(m.CHANNELS)))).sum(axis=1)
    rec["v"] = [[math.nan if base[k].get(c) is None else base[k][c] for c in m.CHANNELS]
                for k in range(n)]  # fmt: skip
    rec["seq"] = np.arange(n)
    rec["t"] = t_start + np.arange(n) / rate
    starts = list(range(0, n, spm))
    heads = {
        c: m._HEADER.pack(m._MAGIC, m._VERSION, m._KIND_MEAS, c)
        for c in {min(spm, n - j) for j in starts}
    }
    one = [heads[min(spm, n - j)] + rec[j : j + spm].tobytes() for j in starts]
    # every actuator sends the same samples (its own key): the payloads are shared
    return [((min(j + spm, n) - 1) / rate, [(a, p) for a in range(n_actuators)])
            for j, p in zip(starts, one, strict=True)]  # fmt: skip


def _generator(args: argparse.Namespace) -> int:
    """The load generator: one HF run of the virtual actuator, pre-encoded once, then put by
    every publisher on its due time (the loop does nothing but wait and put)."""
    import threading

    import zenoh

    from service.sim.actuator import VirtualActuator
    from service.sim.scenarios import load_scenario
    from service.wire import messages as m
    from service.zenoh_util import make_config

    n_per = int(round(args.duration * args.rate))
    # one actuator's HF run, reused by every generator actuator (own key, same seq and t);
    # no wrap: a jump back in the trajectory would make the monitors diverge
    va = VirtualActuator(load_scenario("demo"), rate_hz=args.rate)
    base = va.produce(n_per)
    t_start = time.time() + 2.0  # sample clock: Unix time, so the daemon can measure age
    sched = _payloads(base, args.actuators, args.spm, args.rate, t_start)
    cpu_setup = time.process_time()
    with zenoh.open(make_config("client", connect=[args.connect])) as s:
        pubs = [
            s.declare_publisher(
                m.KEY_MEAS.format(aircraft=f"AC{a // 4:03d}", actuator=f"act{a % 4}"),
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
            for a in range(args.actuators)
        ]
        sched = [(due, [(pubs[a].put, p) for a, p in group]) for due, group in sched]
        time.sleep(max(0.0, t_start - time.time()))
        # the pacing clock on the sample clock: had the set-up overrun t_start, the messages
        # would go out late (counted in max_late_s), not with a shifted time stamp
        w0 = time.monotonic() + (t_start - time.time())
        cpu0 = time.process_time()
        late = 0.0
        ev = threading.Event()
        mono = time.monotonic
        for due, group in sched:
            wait = w0 + due - mono()
            if wait > 0.0005:
                ev.wait(wait)
            else:
                late = max(late, -wait)
            for put, payload in group:
                put(payload)
        wall = time.monotonic() - w0
        cpu_run = time.process_time() - cpu0
        time.sleep(0.5)
    print(
        json.dumps(
            {
                "sent_samples": n_per * args.actuators,
                "sent_msgs": sum(len(g) for _, g in sched),
                "wall_s": wall,
                "max_late_s": late,
                "cpu_s": cpu_run,  # the sending loop's (what competes with the daemon)
                "cpu_setup_s": cpu_setup,
            }
        ),
        flush=True,
    )
    return 0


class _NullBank:
    """The ``MonitorBank`` interface the daemon uses, estimating nothing: one output row of
    zeros per sample (the outputs are logged and published as the real bank's)."""

    def __init__(self):
        from service.monitor import Baseline, MonitorConfig

        self.config = MonitorConfig()
        self.baseline = Baseline.default(self.config.model)
        self.ids: dict[str, int] = {}

    def index_of(self, key: str) -> int:
        return self.ids.setdefault(key, len(self.ids))

    def counters_of(self, key: str) -> dict[str, int]:
        return {}

    def c_lk_changes_of(self, key: str) -> int:
        return 0

    def update_arrays(self, ks, t, channels):
        import numpy as np

        from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS, BankRows, RowEvents

        n = len(t)
        z = np.zeros
        return BankRows(
            np.arange(n), np.asarray(t, float), z((n, len(EST_KEYS))), z((n, len(RES_KEYS))),
            z((n, len(HEALTH_KEYS))), RowEvents(n),
        )  # fmt: skip


def _daemon(args: argparse.Namespace) -> int:
    import signal
    import threading

    if args.tree:  # another checkout's daemon (--compare-tree), its log process too (a
        # ``python -c`` child has the working directory first on its path)
        sys.path.insert(0, str(Path(args.tree).resolve()))
        os.chdir(Path(args.tree).resolve())
    import zenoh

    from service.config import ServiceConfig, ZenohSettings
    from service.daemon import Daemon

    monitor = {} if args.model is None else {"monitor": {"model": args.model}}
    cfg = ServiceConfig(
        **monitor,
        station="bench",
        rotate_bytes=None,
        rotate_s=None,
        publish_every=args.publish_every,
        log_every=args.log_every,
        silence_s=30.0,
        zenoh=ZenohSettings(mode="client", connect=[args.connect]),
    )
    bank = _NullBank() if args.monitor == "null" else None
    if args.metrics:
        from service.config import MetricsSettings

        cfg = cfg.model_copy(
            update={"metrics": MetricsSettings(listen=f"127.0.0.1:{args.metrics}")}
        )
    if args.foxglove:
        from service.config import FoxgloveSettings

        cfg = cfg.model_copy(
            update={
                "foxglove": FoxgloveSettings(
                    listen=f"127.0.0.1:{args.foxglove}", every=args.foxglove_every
                )
            }
        )
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    with zenoh.open(cfg.zenoh.to_zenoh()) as session:
        d = Daemon(
            cfg, log_path=args.log, bank=bank, gather_s=args.gather,
        )  # fmt: skip
        prof = None
        if args.profile:
            import cProfile

            prof = cProfile.Profile()
            inner = d.process_pending
            d.process_pending = lambda: prof.runcall(inner)
        d.start(session)
        cpu0 = time.process_time()
        worker = d._worker.native_id if d._worker is not None else None
        lproc = getattr(getattr(d.outputs.logger, "_proc", None), "pid", None)
        th0 = _threads_cpu(os.getpid())
        lg0 = _stat_cpu(f"/proc/{lproc}/stat")[1] if lproc else 0.0
        print("ready", flush=True)
        ppid = os.getppid()
        while not stop.wait(0.5):
            if os.getppid() != ppid:  # the orchestrator died: do not linger
                break
        # report how long the queue takes to empty once the generator has stopped
        t0 = time.monotonic()
        while d.queued and time.monotonic() - t0 < args.drain_cap:
            time.sleep(0.02)
        drain = time.monotonic() - t0
        left = d.queued
        cpu_s = time.process_time() - cpu0
        split = _cpu_split(th0, _threads_cpu(os.getpid()), worker)
        t_stop = time.monotonic()
        st = d.stop()  # the log process writes what it has queued and the summary
        if lproc:  # reaped by stop(): its whole life less what it had spent at "ready"
            import resource

            r = resource.getrusage(resource.RUSAGE_CHILDREN)
            split["log process"] = r.ru_utime + r.ru_stime - lg0
        split["stop_s"] = time.monotonic() - t_stop
    if prof is not None:
        import pstats

        pstats.Stats(prof, stream=sys.stderr).sort_stats("tottime").print_stats(25)
    st["drain_s"] = drain
    st["left_in_queue"] = left
    st["cpu_s"] = cpu_s
    st["cpu_split_s"] = split
    print(json.dumps(st), flush=True)
    return 0


# --------------------------------------------------------------------------- orchestrator


def run_one(
    actuators: int,
    rate: float,
    duration: float,
    monitor: str,
    spm: int = 10,
    publish_every: int = 10,
    drain_cap: float = 60.0,
    log_every: int = 1,
    profile: bool = False,
    gather: float = 0.005,
    viewer: str | None = None,
    every: int = 10,
    model: str | None = None,
    tree: str | None = None,
    scrape_s: float | None = None,
    scrapers: int = 0,
) -> dict:
    """One benchmark run; returns the row of the table. ``viewer``: None (no Foxglove
    server), "layout" (a viewer of one actuator's layout topics) or "all" (of every
    channel). ``scrape_s``: serve ``--metrics`` and scrape it every ``scrape_s`` seconds;
    ``scrapers``: serve it and run that many scrapers without pause (``_scrapers``)."""
    import zenoh

    from service.log import read_log
    from service.zenoh_util import free_port, loopback, make_config

    ep = loopback(free_port())
    fx_port = free_port()
    m_port = free_port()
    view = None
    scraper = None
    router = zenoh.open(make_config("router", [ep]))
    tmp = tempfile.mkdtemp(prefix="servowatch-bench-")
    log = Path(tmp) / "bench.mcap"
    py = sys.executable
    me = str(Path(__file__).resolve())
    common = ["--connect", ep]
    dproc = None
    try:
        dproc = subprocess.Popen(
            [
                py,
                me,
                "_daemon",
                *common,
                "--log",
                str(log),
                "--monitor",
                monitor,
                "--publish-every",
                str(publish_every),
                "--drain-cap",
                str(drain_cap),
                "--log-every",
                str(log_every),
                *(["--profile"] if profile else []),
                "--gather",
                str(gather),
                *(["--foxglove", str(fx_port), "--foxglove-every", str(every)] if viewer else []),
                *(["--model", model] if model else []),
                *(["--tree", tree] if tree else []),
                *(["--metrics", str(m_port)] if scrape_s or scrapers else []),
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert dproc.stdout.readline().strip() == "ready"
        if viewer:
            view = _Viewer(fx_port, viewer)
        if scrape_s:
            scraper = _Scraper(m_port, scrape_s)
        if scrapers:
            scraper = subprocess.Popen(
                [py, me, "_scrapers", "--metrics", str(m_port), "--scrapers", str(scrapers)],
                stdout=subprocess.PIPE, text=True,
            )  # fmt: skip
            time.sleep(1.0)
        time.sleep(0.5)
        cpu_router0 = time.process_time()
        g = subprocess.run(
            [
                py,
                me,
                "_gen",
                *common,
                "--actuators",
                str(actuators),
                "--rate",
                str(rate),
                "--duration",
                str(duration),
                "--spm",
                str(spm),
            ],
            capture_output=True,
            text=True,
            timeout=duration + 120,
        )
        if g.returncode != 0 or not g.stdout.strip():
            dproc.kill()
            raise RuntimeError(f"load generator failed ({g.returncode}):\n{g.stderr[-3000:]}")
        gen = json.loads(g.stdout.strip().splitlines()[-1])
        cpu_router = time.process_time() - cpu_router0
        dproc.terminate()
        out, _ = dproc.communicate(timeout=drain_cap + 60)
        st = json.loads(out.strip().splitlines()[-1])
    finally:
        if dproc is not None and dproc.poll() is None:  # a failed run leaves no daemon behind
            dproc.kill()
            dproc.wait(10)
        router.close()
        if view is not None:
            view.close()
        scraped = {}
        if isinstance(scraper, subprocess.Popen):
            scraper.terminate()
            out_s, _ = scraper.communicate(timeout=30)
            scraped = json.loads(out_s.strip().splitlines()[-1]) if out_s.strip() else {}
            scraper = None
        if scraper is not None:
            scraper.close()
    logged = sum(1 for topic, _t, _m in read_log(log) if topic.endswith("/meas"))
    acts = st["actuators"].values()
    processed = sum(a["outputs"] for a in acts)
    with_bad = sum(a["bad_total"] for a in acts)
    received = sum(a["messages"] for a in acts)
    os.unlink(log)
    os.rmdir(tmp)
    return {
        "code": "this" if tree is None else Path(tree).name,
        "model": st.get("model") or model or "default",
        "actuators": actuators,
        "rate_hz": rate,
        "monitor": monitor,
        "log_every": log_every,
        "duration_s": duration,
        "sent": gen["sent_samples"],
        "sent_msgs": gen["sent_msgs"],
        "received_msgs": received,
        "accepted": st["samples"],
        "logged": logged,
        "processed": processed,
        "dropped": st["dropped"],
        "bad": with_bad,
        "gaps": sum(a["gaps"] for a in acts),
        "lat_p50_ms": st["latency_ms"]["p50"],
        "lat_p99_ms": st["latency_ms"]["p99"],
        "age_p50_ms": st["age_ms"]["p50"],
        "age_p99_ms": st["age_ms"]["p99"],
        "busy": st["busy_fraction"],
        "drain_s": st["drain_s"],
        "left_in_queue": st["left_in_queue"],
        "gen_late_s": gen["max_late_s"],
        "viewer": viewer or "none",
        "every": every if viewer else None,
        "cpu_s": st["cpu_s"],
        "cpu_us_per_sample": 1e6 * st["cpu_s"] / max(1, st["samples"]),
        # CPU per accepted sample [us] of each process (the daemon's by thread group)
        "cpu_split_us": {
            **{
                f"daemon {k}": 1e6 * v / max(1, st["samples"])
                for k, v in st.get("cpu_split_s", {}).items()
                if k != "stop_s"
            },
            "generator": 1e6 * gen.get("cpu_s", float("nan")) / max(1, st["samples"]),
            "router (bench process)": 1e6 * cpu_router / max(1, st["samples"]),
        },  # fmt: skip
        "loadavg": os.getloadavg(),
        "viewer_msgs": 0 if view is None else view.received,
        "viewer_subscriptions": 0 if view is None else len(view.subs),
        "feed": st.get("foxglove"),
        "scrape_s": scrape_s,
        "scrapes": 0 if scraper is None else len(scraper.times),
        "scrape_ms": [] if scraper is None else [1e3 * x for x in scraper.times],
        "scrape_errors": 0 if scraper is None else scraper.errors,
        "scrapers": scrapers,
        "scraped": scraped,
        "keeps_up": st["dropped"] == 0
        and st["drain_s"] < 1.0
        and st["samples"] == gen["sent_samples"]
        and (st["latency_ms"]["p99"] or 0.0) < 1000.0,
    }


class _Viewer:
    """A Foxglove viewer in a thread: subscribes to the channels it wants as they are
    advertised ("layout": est, residual, health, events of the first actuator; "all":
    every channel) and reads and counts the messages."""

    def __init__(self, port: int, which: str) -> None:
        import threading

        sys.path.insert(0, str(ROOT / "tests"))
        from _foxglove_ws import FoxgloveClient

        end = time.monotonic() + 30
        while True:
            try:
                self.c = FoxgloveClient("127.0.0.1", port).connect()
                break
            except OSError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.1)
        self.which = which
        self.subs: dict[int, int] = {}  # channel id -> subscription id
        self.received = 0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _wanted(self, topic: str) -> bool:
        if self.which == "all":
            return True
        return topic.startswith("/fleet/AC000/act0/") and topic.rsplit("/", 1)[-1] in (
            "est", "residual", "health", "events")  # fmt: skip

    def _run(self) -> None:
        from _foxglove_ws import MessageData

        while not self._stop.is_set():
            try:
                r = self.c.recv(timeout=0.5)
            except TimeoutError:
                continue
            except (OSError, ConnectionError):
                return
            if isinstance(r, MessageData):
                self.received += 1
            elif r.get("op") == "advertise":
                new = {ch["id"]: len(self.subs) + k + 1 for k, ch in enumerate(
                    x for x in r["channels"] if self._wanted(x["topic"]))}  # fmt: skip
                if new:
                    self.subs.update(new)
                    self.c.subscribe({s: c for c, s in new.items()})

    def close(self) -> None:
        self._stop.set()
        self._t.join(5)
        self.c.close()


def _scrapers(args: argparse.Namespace) -> int:
    """``GET /metrics`` of port ``--metrics`` in ``--scrapers`` threads, each without pause,
    until SIGTERM; prints the answers counted by status."""
    import signal
    import threading
    import urllib.error
    import urllib.request

    url = f"http://127.0.0.1:{args.metrics}/metrics"
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    counts: dict[str, int] = {}
    lock = threading.Lock()

    def run() -> None:
        while not stop.is_set():
            try:
                with urllib.request.urlopen(url, timeout=10) as r:
                    r.read()
                    k = str(r.status)
            except urllib.error.HTTPError as e:
                k = str(e.code)
            except OSError:
                k = "error"
                time.sleep(0.01)
            with lock:
                counts[k] = counts.get(k, 0) + 1

    ts = [threading.Thread(target=run, daemon=True) for _ in range(args.scrapers)]
    for t in ts:
        t.start()
    while not stop.wait(0.2):
        pass
    with lock:
        print(json.dumps(counts), flush=True)
    return 0


def _metrics_load(args: argparse.Namespace) -> int:
    import statistics

    n, mon = args.actuators or 100, args.monitor or "real"
    rows = []
    for k in [0, args.metrics_load] * args.repeat:
        print(f"run: {n} actuators x {args.rate:g} Hz, {args.duration:g} s, monitor {mon}, "
              f"{k} scrapers ...", file=sys.stderr, flush=True)  # fmt: skip
        row = run_one(
            n, args.rate, args.duration, mon, args.spm, args.publish_every, args.drain_cap,
            args.log_every, False, args.gather, scrapers=k,
        )  # fmt: skip
        print("  " + json.dumps(row), file=sys.stderr, flush=True)
        rows.append(row)
    print(f"servowatch metrics under load ({os.cpu_count()} CPUs): {n} actuators x "
          f"{args.rate:g} Hz, {args.duration:g} s, monitor {mon}")  # fmt: skip
    print(f"{'scrapers':>8} {'runs':>4} {'accepted':>9} {'dropped':>7} "
          f"{'health p99 ms (each run)':>26} {'median':>7} {'ratio':>6} "
          f"{'scrapes 200/503/err':>20}")  # fmt: skip
    med = {}
    for k in (0, args.metrics_load):
        v = [r for r in rows if r["scrapers"] == k]
        med[k] = statistics.median(r["lat_p99_ms"] or math.nan for r in v)
        each = " ".join(_f(r["lat_p99_ms"]) for r in v)
        sc = (
            "-"
            if not k
            else "/".join(
                str(sum(r["scraped"].get(c, 0) for r in v)) for c in ("200", "503", "error")
            )
        )
        ratio = "-" if not k else f"{med[k] / med[0]:.2f}"
        print(f"{k:>8} {len(v):>4} {min(r['accepted'] for r in v):>9} "
              f"{max(r['dropped'] for r in v):>7} {each:>26} {med[k]:>7.1f} {ratio:>6} "
              f"{sc:>20}")  # fmt: skip
    print("health p99 = receipt of a sample by the daemon -> its health output, 99th percentile "
          "over the run's last 50 000 outputs; ratio = median p99 with the scrapers / without; "
          "target <= 2")  # fmt: skip
    if args.json:
        print(json.dumps(rows))
    return 0


class _Scraper:
    """``GET /metrics`` of the daemon every ``every_s`` seconds in a thread, timed."""

    def __init__(self, port: int, every_s: float) -> None:
        import threading

        self.url = f"http://127.0.0.1:{port}/metrics"
        self.every_s = every_s
        self.times: list[float] = []
        self.errors = 0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        import urllib.request

        while not self._stop.wait(self.every_s):
            t0 = time.perf_counter()
            try:
                with urllib.request.urlopen(self.url, timeout=5) as r:
                    r.read()
                self.times.append(time.perf_counter() - t0)
            except OSError:
                self.errors += 1

    def close(self) -> None:
        self._stop.set()
        self._t.join(10)


def print_cost(rows: list[dict]) -> None:
    """The --viewer-cost table (medians over the repeats) and the cost figures."""
    import statistics

    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["viewer"], r["every"]), []).append(r)
    med = {k: statistics.median(r["cpu_us_per_sample"] for r in v) for k, v in groups.items()}
    base = med.get(("none", None))
    print(f"{'viewer':>8} {'every':>5} {'runs':>4} {'samples':>8} {'dropped':>7} "
          f"{'viewer msgs':>11} {'cpu us/sample (each run)':>28} {'median':>7} "
          f"{'throughput cost':>15}")  # fmt: skip
    for k, v in groups.items():
        cost = "-" if base is None or k == ("none", None) else f"{100 * (1 - base / med[k]):.1f} %"
        each = " ".join(f"{r['cpu_us_per_sample']:.1f}" for r in v)
        print(f"{k[0]:>8} {k[1] or '-':>5} {len(v):>4} {v[0]['accepted']:>8} "
              f"{max(r['dropped'] for r in v):>7} {v[0]['viewer_msgs']:>11} {each:>28} "
              f"{med[k]:>7.2f} {cost:>15}")  # fmt: skip
    print("cpu = the daemon process's CPU time (all threads) over the run; throughput cost = "
          "1 - median cpu/sample without the Foxglove server / median with the viewer; the "
          "configurations alternate run by run")  # fmt: skip


def _f(v, spec=".1f"):
    return "-" if v is None else format(v, spec)


def print_split(rows: list[dict]) -> None:
    """CPU per accepted sample of each process and the daemon's threads."""
    keys = ["daemon worker", "daemon monitor steps", "daemon intake callbacks", "daemon zenoh",
            "daemon other", "daemon log process"]  # fmt: skip
    print(
        f"{'code':>6} {'model':>7} {'act':>4} {'worker':>7} {'steps':>6} {'intake':>6} {'zenoh':>6} {'other':>6} "
        f"{'log proc':>8} {'DAEMON':>7} {'gen':>6} {'router':>6}  load avg (1/5/15 min)"
    )
    for r in rows:
        c = r.get("cpu_split_us") or {}
        daemon = sum(c.get(k, 0.0) for k in keys)
        print(f"{r['code'][:6]:>6} {r['model'] if r['monitor'] == 'real' else '-':>7} "
              f"{r['actuators']:>4} " + " ".join(f"{c.get(k, 0.0):>{w}.1f}" for k, w in
              zip(keys, (7, 6, 6, 6, 6, 8), strict=True)) + f" {daemon:>7.1f} "
              f"{c.get('generator', float('nan')):>6.1f} "
              f"{c.get('router (bench process)', float('nan')):>6.1f}  "
              + "/".join(f"{x:.1f}" for x in r.get("loadavg", ())))  # fmt: skip
    print(
        "CPU time per accepted sample [us] over the run: the daemon's worker thread, its "
        "monitor's step threads, the intake (Zenoh's callbacks into Python), Zenoh's own threads, "
        "its other threads, its MCAP log process (DAEMON = their sum, the "
        "daemon as a whole), the load generator, the router (this process)"
    )


def print_table(rows: list[dict]) -> None:
    hdr = (
        f"{'code':>6} {'model':>7} {'act x Hz':>10} {'monitor':>7} {'log est':>7} {'sent':>8} {'accepted':>8} {'logged':>8} "
        f"{'processed':>9} {'dropped':>7} {'lat p50':>8} {'lat p99':>8} {'age p50':>8} "
        f"{'age p99':>8} {'busy':>5} {'drain s':>7} {'keeps up':>8}"
    )
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        print(
            f"{r['code'][:6]:>6} {r['model'] if r['monitor'] == 'real' else '-':>7} "
            f"{r['actuators']:>4} x {r['rate_hz']:<4g} {r['monitor']:>7} "
            f"{'1/' + str(r['log_every']):>7} {r['sent']:>8} "
            f"{r['accepted']:>8} {r['logged']:>8} {r['processed']:>9} {r['dropped']:>7} "
            f"{_f(r['lat_p50_ms']):>8} {_f(r['lat_p99_ms']):>8} {_f(r['age_p50_ms']):>8} "
            f"{_f(r['age_p99_ms']):>8} {r['busy']:>5.2f} {r['drain_s']:>7.1f} "
            f"{'yes' if r['keeps_up'] else 'NO':>8}"
        )
    print(
        "latencies in ms: lat = receipt by the daemon -> health output; age = sample time "
        "-> health output (includes the publisher's 10-sample batching); log est = est and "
        "residual logged for 1 output in N (every sample is always logged)"
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "role", nargs="?", default="bench", choices=("bench", "_gen", "_daemon", "_scrapers")
    )
    p.add_argument("--connect")
    p.add_argument("--log")
    p.add_argument("--actuators", type=int, default=None)
    p.add_argument("--rate", type=float, default=1000.0)
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--spm", type=int, default=10, help="samples per message")
    p.add_argument("--monitor", choices=("real", "null"), default=None)
    p.add_argument("--publish-every", type=int, default=10)
    p.add_argument("--log-every", type=int, default=1, help="log est/res every N outputs")
    p.add_argument("--drain-cap", type=float, default=60.0)
    p.add_argument("--json", action="store_true")
    p.add_argument("--gather", type=float, default=0.005, help="daemon batch gathering [s]")
    p.add_argument("--profile", action="store_true", help="profile the daemon's worker")
    p.add_argument("--foxglove", type=int, default=None, help=argparse.SUPPRESS)  # _daemon
    p.add_argument("--metrics", type=int, default=None, help=argparse.SUPPRESS)  # _daemon
    p.add_argument(
        "--metrics-cost", action="store_true",
        help="the cost of the OpenMetrics endpoint: runs without it, and with it scraped every "
        "second (default 10 actuators, real monitor)",
    )  # fmt: skip
    p.add_argument("--foxglove-every", type=int, default=10, help=argparse.SUPPRESS)
    p.add_argument("--scrapers", type=int, default=0, help=argparse.SUPPRESS)  # _scrapers
    p.add_argument(
        "--metrics-load", type=int, default=0, metavar="N",
        help="health latency p99 without and with N scrapers of /metrics without pause",
    )  # fmt: skip
    p.add_argument("--repeat", type=int, default=1, help="--viewer-cost: runs per setting")
    p.add_argument(
        "--viewer-cost", action="store_true",
        help="the cost of a Foxglove viewer: runs without, with a layout viewer, with an "
        "all-channels viewer (default 10 actuators, real monitor)",
    )  # fmt: skip
    p.add_argument("--model", default=None, help=argparse.SUPPRESS)  # the daemon's
    p.add_argument("--tree", default=None, help=argparse.SUPPRESS)  # the daemon's
    p.add_argument("--models", default=None, help="monitor process models, e.g. WH,C5")
    p.add_argument("--compare-tree", default=None, help="also run every row on this checkout")
    args = p.parse_args(argv)
    if args.role == "_gen":
        return _generator(args)
    if args.role == "_daemon":
        return _daemon(args)
    if args.role == "_scrapers":
        return _scrapers(args)
    if args.metrics_load:
        return _metrics_load(args)
    if args.viewer_cost:
        return _viewer_cost(args)
    if args.metrics_cost:
        return _metrics_cost(args)
    default_plan = args.actuators is None and args.monitor is None
    if not default_plan:
        plan = [(args.actuators or 20, args.monitor or "real", args.log_every)]
    else:
        plan = [
            (20, "null", 1),
            (20, "null", 10),
            (1, "real", 1),
            (5, "real", 10),
            (10, "real", 10),
            (20, "real", 10),
        ]
    models = [None] if args.models is None else args.models.split(",")
    trees = [None] if args.compare_tree is None else [None, args.compare_tree]
    plan = [(n, mon, le, md, tr) for tr in trees for n, mon, le in plan
            for md in (models if mon == "real" else [None])]  # fmt: skip
    rows = []
    for n, mon, le, model, tree in plan:
        dur = args.duration
        if default_plan and mon == "real" and n > 1:
            dur = min(dur, 5.0)  # keep `make bench` short
        print(
            f"run: {n} actuators x {args.rate:g} Hz, {dur:g} s, monitor {mon} {model or ''}, "
            f"log_every {le}, code {tree or 'this'} ...",
            file=sys.stderr,
            flush=True,
        )
        try:
            row = run_one(
                n, args.rate, dur, mon, args.spm, args.publish_every, args.drain_cap, le,
                args.profile, args.gather, model=model, tree=tree,
            )  # fmt: skip
        except Exception as e:  # report the others
            print(f"  failed: {e}", file=sys.stderr, flush=True)
            continue
        print("  " + json.dumps(row), file=sys.stderr, flush=True)
        rows.append(row)
    print(
        f"servowatch daemon benchmark ({os.cpu_count()} CPUs), {args.spm} samples/message, "
        f"publish_every {args.publish_every}"
    )
    print_table(rows)
    print()
    print_split(rows)
    if args.json:
        print(json.dumps(rows))
    return 0


def _viewer_cost(args: argparse.Namespace) -> int:
    n, mon = args.actuators or 10, args.monitor or "real"
    rows = []
    plan = [(None, 10), ("layout", 10), ("all", 10), ("layout", 1)] * args.repeat
    for viewer, every in plan:
        print(f"run: {n} actuators x {args.rate:g} Hz, {args.duration:g} s, monitor {mon}, "
              f"viewer {viewer or 'none (no Foxglove server)'}, every {every} ...",
              file=sys.stderr, flush=True)  # fmt: skip
        row = run_one(
            n, args.rate, args.duration, mon, args.spm, args.publish_every, args.drain_cap,
            args.log_every, False, args.gather, viewer, every,
        )  # fmt: skip
        print("  " + json.dumps(row), file=sys.stderr, flush=True)
        rows.append(row)
    print(f"servowatch Foxglove viewer cost ({os.cpu_count()} CPUs): {n} actuators x "
          f"{args.rate:g} Hz, {args.duration:g} s, monitor {mon}")  # fmt: skip
    print_cost(rows)
    if args.json:
        print(json.dumps(rows))
    return 0


def _metrics_cost(args: argparse.Namespace) -> int:
    import statistics

    n, mon = args.actuators or 10, args.monitor or "real"
    rows = []
    for scrape_s in [None, 1.0] * args.repeat:
        what = f"scraped every {scrape_s:g} s" if scrape_s else "off"
        print(f"run: {n} actuators x {args.rate:g} Hz, {args.duration:g} s, monitor {mon}, "
              f"metrics {what} ...",
              file=sys.stderr, flush=True)  # fmt: skip
        row = run_one(
            n, args.rate, args.duration, mon, args.spm, args.publish_every, args.drain_cap,
            args.log_every, False, args.gather, scrape_s=scrape_s,
        )  # fmt: skip
        print("  " + json.dumps(row), file=sys.stderr, flush=True)
        rows.append(row)
    print(f"servowatch metrics endpoint cost ({os.cpu_count()} CPUs): {n} actuators x "
          f"{args.rate:g} Hz, {args.duration:g} s, monitor {mon}")  # fmt: skip
    print(f"{'metrics':>16} {'runs':>4} {'samples':>8} {'dropped':>7} {'scrapes':>7} "
          f"{'scrape ms p50/max':>17} {'cpu us/sample (each run)':>28} {'median':>7} "
          f"{'throughput cost':>15}")  # fmt: skip
    med = {}
    for key in (None, 1.0):
        v = [r for r in rows if r["scrape_s"] == key]
        med[key] = statistics.median(r["cpu_us_per_sample"] for r in v)
        ms = [x for r in v for x in r["scrape_ms"]]
        sc = "-" if not ms else f"{statistics.median(ms):.1f}/{max(ms):.1f}"
        cost = "-" if key is None else f"{100 * (1 - med[None] / med[key]):.1f} %"
        each = " ".join(f"{r['cpu_us_per_sample']:.1f}" for r in v)
        label = "off" if key is None else f"scraped every {key:g} s"
        print(f"{label:>16} {len(v):>4} {v[0]['accepted']:>8} {max(r['dropped'] for r in v):>7} "
              f"{sum(r['scrapes'] for r in v):>7} {sc:>17} {each:>28} {med[key]:>7.2f} "
              f"{cost:>15}")  # fmt: skip
    print("cpu = the daemon process's CPU time (all threads, the endpoint's too) over the run; "
          "throughput cost = 1 - median cpu/sample without / with the endpoint")  # fmt: skip
    print(
        "one scrape in process (the status snapshot and its exposition; CPU time, median of "
        "20): " + ", ".join(f"{n} units {ms:.2f} ms" for n, ms in scrape_cpu_ms((10, 100, 1000)))
    )
    if args.json:
        print(json.dumps(rows))
    return 0


def scrape_cpu_ms(units: tuple[int, ...]) -> list[tuple[int, float]]:
    """CPU milliseconds of one scrape (``Daemon.status()`` and its exposition) of a daemon
    that monitors ``n`` units (20 samples each, the real monitor), for each ``n``."""
    import statistics

    from prometheus_client.exposition import generate_latest

    from service.config import MetricsSettings, ServiceConfig
    from service.daemon import Daemon
    from service.sim.actuator import VirtualActuator
    from service.sim.scenarios import load_scenario
    from service.wire import messages as m

    base = VirtualActuator(load_scenario("demo"), rate_hz=1000.0).produce(20)
    out = []
    for n in units:
        tmp = tempfile.mkdtemp(prefix="servowatch-bench-")
        cfg = ServiceConfig(store="off", metrics=MetricsSettings(listen="127.0.0.1:0"))
        d = Daemon(cfg, log_path=Path(tmp) / "s.mcap", log_process=False, gather_s=0,
                   max_batch=100_000)  # fmt: skip
        for a in range(n):
            rows = [dict(s, seq=k, t=1.0 + k / 1000.0) for k, s in enumerate(base)]
            d.submit(m.KEY_MEAS.format(aircraft=f"AC{a // 4:03d}", actuator=f"act{a % 4}"),
                     m.encode_meas(rows))  # fmt: skip
        while d.queued:
            d.process_pending()
        times = []
        for _ in range(20):
            t0 = time.process_time()
            generate_latest(d.metrics.registry)
            times.append(time.process_time() - t0)
        d.stop()
        out.append((n, 1e3 * statistics.median(times)))
    return out


if __name__ == "__main__":
    sys.exit(main())
