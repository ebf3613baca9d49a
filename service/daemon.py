"""The monitoring daemon: Zenoh samples in, one monitor per actuator, estimates out, MCAP log.

Data path (design.md, "Data flow" and "Backpressure"):

* the Zenoh subscriber callback only appends ``(key, payload, t_recv)`` to a bounded queue
  (a full queue drops the new message and counts it against its actuator);
* one worker thread drains the queue every tick, decodes and validates each message into
  arrays (``service.messages.decode_meas_arrays``), checks sequence numbers and sample times
  per actuator, logs every accepted sample, feeds the whole tick's samples to the monitors in
  one ``MonitorBank.update_arrays`` call (no per-sample dicts; outputs are logged as blocks of
  rows, ``McapLogger.log_block``), logs the estimate and residual of every ``log_every``-th
  output (default 1: every one), health every ``publish_every``-th output, and every alarm
  event (with the est/res/health of that sample), and publishes est/res/health every
  ``publish_every``-th output per actuator;
* the status queryable ``monitor/{station}/{shard}/status`` answers a JSON snapshot.

Bad input (malformed payload, wrong schema, NaN/inf, duplicate or out-of-order samples,
oversize messages, unparseable keys) is counted per actuator and logged at a limited rate;
it never stops the worker and never discards a good sample of the same message stream.

A sample is accepted when its time is later than the actuator's last accepted sample; a
sequence number that falls back while time advances is a publisher restart (counted), a
sequence that jumps forward is a gap (missing samples counted). Only accepted samples reach
the monitor and the ``meas`` log topic, so a replay of the log feeds the monitor exactly the
live input.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from service import messages as m
from service.jsonutil import event_dict, flat, jsonable
from service.proclog import MEAS_LOG_FIELDS, ProcessLogger, meas_log_values

__all__ = [
    "ActuatorState",
    "Daemon",
    "ProcessLogger",
    "MAX_ACTUATORS",
    "RateLimitedLog",
    "add_zenoh_arguments",
    "service_config_from_args",
    "default_log_path",
    "percentiles",
    "sd_notify",
]

log = logging.getLogger("servowatch.daemon")

#: actuators a daemon tracks at most; samples of further ones count as ``unknown_actuator``
MAX_ACTUATORS = 1000
INVALID_KEY = "(invalid key)"


def _meas_dict(a: m.MeasArrays, j: int) -> dict[str, Any]:
    """Sample j as ``decode_meas_dicts`` gives it (None: absent channel)."""
    d: dict[str, Any] = {
        c: (None if v != v else v) for c, v in zip(m.CHANNELS, a.values[j].tolist(), strict=True)
    }
    d["seq"] = int(a.seq[j])
    d["t"] = float(a.t[j])
    return d


# --------------------------------------------------------------------------- helpers


def sd_notify(state: str, env: dict[str, str] | None = None) -> bool:
    """Send ``state`` (``READY=1``, ``WATCHDOG=1``, ...) to systemd's ``NOTIFY_SOCKET``.

    A datagram on the unix socket named by the variable (``@`` = abstract namespace), as
    sd_notify(3) does. Returns False (and does nothing) when the variable is unset.
    """
    addr = (env if env is not None else os.environ).get("NOTIFY_SOCKET")
    if not addr:
        return False
    if addr.startswith("@"):
        addr = "\0" + addr[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
            s.setblocking(False)  # a full receiver queue must never stall the worker
            s.sendto(state.encode(), addr)
        return True
    except BlockingIOError:
        _NOTIFY_LOG.warning("notify", "sd_notify(%s): the notify socket is full; dropped", state)
        return False
    except OSError as e:
        log.warning("sd_notify(%s) failed: %s", state, e)
        return False


def watchdog_interval(env: dict[str, str] | None = None) -> float | None:
    """Half of systemd's ``WATCHDOG_USEC`` in seconds (how often to ping), or None."""
    env = env if env is not None else os.environ
    usec = env.get("WATCHDOG_USEC")
    pid = env.get("WATCHDOG_PID")
    if not usec or (pid and pid != str(os.getpid())):
        return None
    try:
        return max(0.05, int(usec) / 2e6)
    except ValueError:
        return None


def percentiles(values: Iterable[float], qs: Sequence[float] = (50, 99)) -> list[float | None]:
    """Percentiles (nearest-rank on the sorted values) or None for an empty set."""
    v = sorted(values)
    if not v:
        return [None for _ in qs]
    out = []
    for q in qs:
        k = min(len(v) - 1, max(0, int(math.ceil(q / 100 * len(v))) - 1))
        out.append(v[k])
    return out


class RateLimitedLog:
    """Log at most one message per ``interval_s`` per key, counting what it suppressed."""

    def __init__(self, logger: logging.Logger, interval_s: float = 5.0):
        self.logger = logger
        self.interval_s = interval_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def warning(self, key: str, msg: str, *args: Any) -> bool:
        """Log ``msg % args`` under ``key`` unless one was logged less than interval_s ago."""
        now = time.monotonic()
        last = self._last.get(key)
        if last is not None and now - last < self.interval_s:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return False
        n = self._suppressed.pop(key, 0)
        self._last[key] = now
        suffix = f" ({n} similar suppressed)" if n else ""
        self.logger.warning(msg + suffix, *args)
        return True


_NOTIFY_LOG = RateLimitedLog(log, 30.0)


def default_log_path(log_dir: Path, station: str, shard: str, prefix: str = "servowatch") -> Path:
    """``{log_dir}/{prefix}-{station}-{shard}-{UTC time}.mcap``."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    return Path(log_dir) / f"{prefix}-{station}-{shard}-{stamp}.mcap"


def add_zenoh_arguments(parser) -> None:
    """``--config``, ``--connect``, ``--listen``, ``--mode`` shared by the service commands."""
    parser.add_argument("--config", help="service TOML file (SERVOWATCH_* env overrides apply)")
    parser.add_argument(
        "--connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable; "
        "replaces the config's)",
    )
    parser.add_argument(
        "--listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on (repeatable; replaces the config's)",
    )
    parser.add_argument(
        "--mode",
        choices=("peer", "client", "router"),
        default=None,
        help="Zenoh mode (default: the config's; a peer with nothing to "
        "listen on runs as a client)",
    )
    from service.config import add_tls_arguments  # --tls-root-ca/--tls-cert/--tls-key paths

    add_tls_arguments(parser)


def service_config_from_args(args) -> Any:
    """``load_config(args.config)`` with the command line's Zenoh overrides applied."""
    from service.config import ConfigError, ZenohSettings, load_config, tls_overrides

    cfg = load_config(getattr(args, "config", None))
    z = cfg.zenoh.model_dump()
    if getattr(args, "connect", None):
        z["connect"] = list(args.connect)
    if getattr(args, "listen", None):
        z["listen"] = list(args.listen)
    if getattr(args, "mode", None):
        z["mode"] = args.mode
    elif z["mode"] == "peer" and not z["listen"] and z["connect"]:
        z["mode"] = "client"
    z = tls_overrides(args, z)
    try:
        zs = ZenohSettings.model_validate(z)
    except ValueError as e:  # pydantic.ValidationError: name the field, skip the URL
        errs = getattr(e, "errors", None)
        if errs is None:
            raise
        err = errs()[0]
        loc = ".".join(str(x) for x in err["loc"])
        raise ConfigError(err["msg"], f"zenoh.{loc}", "command line") from None
    return cfg.model_copy(update={"zenoh": zs})


@dataclass
class ActuatorState:
    """Counters and latest outputs of one actuator (``fleet/{aircraft}/{actuator}``)."""

    aircraft: str
    actuator: str
    messages: int = 0
    samples: int = 0  # accepted samples (fed to the monitor and logged)
    dropped: int = 0  # messages dropped by the full queue
    gaps: int = 0  # samples missing according to sequence numbers
    restarts: int = 0  # sequence fell back while time advanced
    outputs: int = 0  # monitor outputs
    published: int = 0
    bad: dict[str, int] = field(default_factory=dict)  # reason -> count
    last_seq: int | None = None
    last_t: float | None = None
    last_recv: float | None = None  # time.monotonic() of the last message
    silent: bool = False
    est: dict = field(default_factory=dict)
    health: dict = field(default_factory=dict)
    alarms: dict[str, Any] = field(default_factory=dict)  # kind -> last event dict (active)
    events: deque = field(default_factory=lambda: deque(maxlen=20))
    lazy: Any = None  # (BankRows, row) of the latest output when its dicts were not built

    @property
    def name(self) -> str:
        return f"{self.aircraft}/{self.actuator}"

    def count_bad(self, reason: str, n: int = 1) -> None:
        self.bad[reason] = self.bad.get(reason, 0) + n

    def snapshot(self, now: float) -> dict[str, Any]:
        lazy = self.lazy
        if lazy is not None:  # latest output kept as a row of update_rows
            out = lazy[0].output(lazy[1])
            self.est, self.health = out.est, out.health
        return {
            "aircraft": self.aircraft,
            "actuator": self.actuator,
            "messages": self.messages,
            "samples": self.samples,
            "dropped": self.dropped,
            "gaps": self.gaps,
            "restarts": self.restarts,
            "outputs": self.outputs,
            "published": self.published,
            "bad": dict(self.bad),
            "bad_total": sum(self.bad.values()),
            "last_seq": self.last_seq,
            "last_t": self.last_t,
            "age_s": None if self.last_recv is None else now - self.last_recv,
            "silent": self.silent,
            "est": dict(self.est),
            "health": dict(self.health),
            "alarms": list(self.alarms.values()),
            "events": list(self.events),
        }


_OFF_STATES = {"off", "clear", "cleared", "ok", "normal", "none", "false", "0", "inactive"}


def _is_active(state: Any) -> bool:
    if isinstance(state, bool):
        return state
    return str(state).lower() not in _OFF_STATES


def _output_parts(out: Any) -> tuple[float, dict, dict, dict, list]:
    """(t, est, res, health, events) of a MonitorOutput (object or mapping)."""
    if isinstance(out, dict):
        return (
            out["t"],
            out.get("est", {}),
            out.get("res", {}),
            out.get("health", {}),
            list(out.get("events", [])),
        )
    return out.t, out.est, out.res, out.health, list(out.events or [])


# --------------------------------------------------------------------------- monitors


class _Monitors:
    """One monitor per actuator, updated in one batch per tick.

    Uses ``service.monitor.MonitorBank`` when it exists (``update_many``), else one
    ``Monitor`` per actuator; ``factory`` (tests, benchmarks) replaces both: it is called
    with an actuator id and returns an object with ``update(sample) -> output | None``.
    """

    def __init__(self, monitor_config=None, baseline=None, factory: Callable | None = None):
        self.factory = factory
        self.bank = None
        self.monitors: dict[str, Any] = {}
        if factory is None:
            from service import monitor as mon

            bank_cls = getattr(mon, "MonitorBank", None)
            if bank_cls is not None:
                self.bank = _make_bank(bank_cls, monitor_config, baseline)
            else:
                self.factory = lambda _aid: mon.Monitor(monitor_config, baseline)

    def metadata(self, station: str, shard: str) -> dict[str, str]:
        """MCAP metadata that lets ``service.replay`` rebuild the same monitors."""
        md = {"source": "daemon", "station": station, "shard": shard}
        if self.bank is not None:
            for name, attr in (("monitor_config", "config"), ("baseline", "baseline")):
                obj = getattr(self.bank, attr, None)
                if hasattr(obj, "model_dump_json"):
                    md[name] = obj.model_dump_json()
        return md

    def counters_of(self, aid: str) -> dict[str, int] | None:
        """The monitor's own sample counters for ``aid`` (accepted, skipped, reinit, ...)."""
        fn = getattr(self.bank, "counters_of", None)
        if fn is not None:
            try:
                return dict(fn(aid))
            except KeyError:
                return None
        mon = self.monitors.get(aid)
        c = getattr(mon, "counters", None)
        return dict(c) if isinstance(c, dict) else None

    def reset(self, aid: str) -> None:
        """Forget the state of ``aid`` (a new monitor starts at its next sample)."""
        if self.bank is not None:
            for name in ("reset", "remove", "drop"):
                fn = getattr(self.bank, name, None)
                if fn is not None:
                    with contextlib.suppress(KeyError):
                        fn(aid)
                    return
        self.monitors.pop(aid, None)

    def warm_up(self) -> float:
        """Run a throwaway bank of the same kind on a few synthetic samples, so that JIT
        compilation happens before the first real sample (and before READY). Seconds taken."""
        t0 = time.perf_counter()
        if self.bank is None:
            return 0.0
        try:
            bank = type(self.bank)(self.bank.config, self.bank.baseline)
            p = 10e6
            rows = [
                ("_warm", {"t": k * 1e-3, "x_cmd": 0.0, "i": 0.0, "x_s": 0.0, "x_j": 0.0,
                           "p1": p, "p2": p, "p_sr": 20e6})
                for k in range(5)
            ]  # fmt: skip
            (bank.update_rows if self.rows else bank.update_many)(rows)
        except Exception as e:  # warming up is an optimisation only
            log.warning("monitor warm-up failed: %s", e)
        return time.perf_counter() - t0

    @property
    def arrays(self) -> bool:
        """True when the bank takes samples as arrays (``update_arrays``, no dicts)."""
        return self.bank is not None and hasattr(self.bank, "update_arrays")

    @property
    def rows(self) -> bool:
        """True when the bank offers ``update_rows`` (numpy rows, no per-sample dicts)."""
        return self.bank is not None and hasattr(self.bank, "update_rows")

    def update_many(self, batch: list[tuple[str, dict]]) -> list[Any]:
        if self.bank is not None:
            return list(self.bank.update_many(batch))
        outs = []
        for aid, s in batch:
            mon = self.monitors.get(aid)
            if mon is None:
                mon = self.monitors[aid] = self.factory(aid)
            outs.append(mon.update(s))
        return outs


def _make_bank(bank_cls, monitor_config, baseline):
    for kwargs in (
        {"config": monitor_config, "baseline": baseline},
        {},
    ):
        try:
            return bank_cls(**kwargs)
        except TypeError:
            continue
    return bank_cls(monitor_config, baseline)


# --------------------------------------------------------------------------- daemon


class Daemon:
    """The monitoring daemon (see the module docstring).

    Usable without Zenoh: ``submit(key, payload)`` then ``process_pending()`` (tests). With
    Zenoh: ``start(session)`` declares the subscriber, queryable and liveliness token and
    starts the worker; ``stop()`` stops the inflow, drains the queue, finishes the log.
    """

    def __init__(
        self,
        config: Any = None,
        *,
        log_path: str | Path | None = None,
        logger: Any = None,
        monitor_factory: Callable | None = None,
        baseline: Any = None,
        tick_s: float = 0.05,
        gather_s: float = 0.005,
        max_batch: int = 500,
        bad_log_interval_s: float = 5.0,
        log_every: int | None = None,
        log_process: bool = True,
    ) -> None:
        if config is None:
            from service.config import ServiceConfig

            config = ServiceConfig()
        self.config = config
        self.station = str(getattr(config, "station", "ground1"))
        self.shard = str(getattr(config, "shard", "0"))
        self.key_expr = str(getattr(config, "key_expr", "fleet/**/meas"))
        self.publish_every = max(1, int(getattr(config, "publish_every", 10) or 1))
        if log_every is None:
            log_every = getattr(config, "log_every", 1)
        self.log_every = max(1, int(log_every or 1))
        self.silence_s = float(getattr(config, "silence_s", 2.0) or 2.0)
        self.queue_size = max(1, int(getattr(config, "queue_size", 10000) or 10000))
        self.max_bytes = int(getattr(config, "max_bytes", m.MAX_BYTES) or m.MAX_BYTES)
        self.tick_s = tick_s
        self.gather_s = gather_s
        self.max_batch = max_batch
        if baseline is None and monitor_factory is None:
            baseline = _load_baseline(getattr(config, "baseline", None))
        self.monitors = _Monitors(getattr(config, "monitor", None), baseline, monitor_factory)
        if logger is None:
            from service.mcaplog import McapLogger

            if log_path is None:
                log_path = default_log_path(
                    Path(getattr(config, "log_dir", "logs")),
                    self.station,
                    self.shard,
                    str(getattr(config, "log_name", "servowatch")),
                )
            Path(log_path).parent.mkdir(parents=True, exist_ok=True)
            kw = {
                "rotate_bytes": getattr(config, "rotate_bytes", None),
                "rotate_s": getattr(config, "rotate_s", None),
                "flush_s": float(getattr(config, "flush_s", 1.0) or 1.0),
                "metadata": self.monitors.metadata(self.station, self.shard),
            }
            logger = ProcessLogger(log_path, **kw) if log_process else McapLogger(log_path, **kw)
        self.logger = logger
        self.log_path = Path(log_path) if log_path is not None else None
        self.actuators: dict[str, ActuatorState] = {}
        self.unknown: dict[str, int] = {}  # reason -> count, for keys that name no actuator
        self._queue: deque = deque()
        self._arrival: dict[str, float] = {}  # key -> time.monotonic() of the last message
        self.first_arrival: dict[str, float] = {}  # key -> time.monotonic() of the first one
        self.alive_tokens: dict[str, bool] = {}  # fleet/{ac}/{act}/alive -> token present
        self._wake = threading.Event()
        self._lock = threading.Lock()  # guards self.actuators structure + status snapshot
        self._stop = threading.Event()
        self._notify_lock = threading.Lock()
        self._worker: threading.Thread | None = None
        self._session = None
        self._decl: list[Any] = []
        self._publishers: dict[tuple[str, str], Any] = {}
        self.latency = deque(maxlen=50000)  # receipt -> health output [s]
        self.age = deque(maxlen=50000)  # sample time t -> health output [s] (Unix-time t)
        self.bad_log = RateLimitedLog(log, bad_log_interval_s)
        self.started = time.time()
        self.ticks = 0
        self.busy_s = 0.0
        self.queue_high = 0
        self.errors = 0
        self._closed = False
        self._last_silence_check = 0.0
        self._wd_interval = watchdog_interval()
        self._wd_last = 0.0

    # -- inflow -------------------------------------------------------------------------
    def submit(self, key: str, payload: bytes, t_recv: float | None = None) -> bool:
        """Queue one message (never blocks); False if the queue was full (drop counted)."""
        if len(self._queue) >= self.queue_size:
            self._count_drop(key)
            return False
        t_recv = time.monotonic() if t_recv is None else t_recv
        self._arrival[key] = t_recv  # for silence detection, even while the worker lags
        if key not in self.first_arrival:
            self.first_arrival[key] = t_recv
        self._queue.append((key, payload, t_recv))
        n = len(self._queue)
        if n > self.queue_high:
            self.queue_high = n
        if n == 1 or n % 64 == 0:
            self._wake.set()
        return True

    def _on_zenoh_sample(self, sample) -> None:
        try:
            self.submit(str(sample.key_expr), sample.payload.to_bytes())
        except Exception:  # never let a callback raise into zenoh
            self.errors += 1

    def _count_drop(self, key: str) -> None:
        st = self._state_for_key(key)
        if st is not None:
            st.dropped += 1
        else:
            self.unknown["dropped"] = self.unknown.get("dropped", 0) + 1

    # -- per-actuator state --------------------------------------------------------------
    def _state_for_key(self, key: str) -> ActuatorState | None:
        st = self.actuators.get(key)
        if st is not None:
            return st
        try:
            aircraft, actuator = m.parse_meas_key(key)
        except m.MessageError:
            return None
        with self._lock:
            st = self.actuators.get(key)
            if st is None:
                if len(self.actuators) >= MAX_ACTUATORS:
                    return None
                st = ActuatorState(aircraft, actuator)
                self.actuators[key] = st
                log.info("new actuator %s", st.name)
        return st

    # -- worker -------------------------------------------------------------------------
    def process_pending(self) -> int:
        """Drain the queue once: validate, log, update the monitors, publish. Returns the
        number of samples fed to the monitors."""
        q = self._queue
        if not q:
            return 0
        t0 = time.perf_counter()
        msgs = []
        while q and len(msgs) < self.max_batch:
            msgs.append(q.popleft())
        parts: list[tuple[ActuatorState, str, m.MeasArrays, int, float]] = []
        logger = self.logger
        log_payload = getattr(logger, "log_payload", None)
        log_block = getattr(logger, "log_block", None)
        for key, payload, t_recv in msgs:
            st = self._state_for_key(key)
            if st is None:
                reason = "unknown_actuator" if key.endswith("/meas") else "invalid_key"
                try:
                    m.parse_meas_key(key)
                except m.MessageError:
                    reason = "invalid_key"
                self.unknown[reason] = self.unknown.get(reason, 0) + 1
                self.bad_log.warning("key:" + reason, "%s: %s", reason, key[:200])
                continue
            st.messages += 1
            st.last_recv = t_recv
            if st.silent:
                st.silent = False
                self._service_event(st, "resumed", st.last_t)
            try:
                a = m.decode_meas_arrays(payload, self.max_bytes)
            except m.MessageError as e:
                reason = _reason(e, payload)
                st.count_bad(reason)
                self.bad_log.warning(st.name, "bad message from %s: %s (%s)", st.name, e, reason)
                continue
            j0 = self._accept(st, a)
            n = len(a.t)
            if j0 >= n:
                continue
            topic = m.mcap_topic(st.aircraft, st.actuator, "meas")
            if log_payload is not None:  # the log process decodes the payload again
                log_payload(topic, payload, None if j0 == 0 else list(range(j0, n)))
            elif log_block is not None:
                log_block(
                    topic, a.t[j0:], MEAS_LOG_FIELDS, meas_log_values(a, j0), int_fields=("seq",)
                )
            else:
                for j in range(j0, n):
                    logger.log(topic, float(a.t[j]), _meas_dict(a, j))
            parts.append((st, key, a, j0, t_recv))
        n_fed = sum(len(p[2].t) - p[3] for p in parts)
        if parts:
            try:
                if self.monitors.arrays:
                    self._update_arrays(parts)
                else:
                    self._update_dicts(parts)
            except Exception as e:  # a monitor failure must not kill the daemon
                self.errors += 1
                log.exception("monitor update failed: %s", e)
        commit = getattr(logger, "commit", None)
        if commit is not None:
            commit()
        self.ticks += 1
        self.busy_s += time.perf_counter() - t0
        return n_fed

    def _accept(self, st: ActuatorState, a: m.MeasArrays) -> int:
        """Sequence and time checks of one decoded message against the actuator's last
        accepted sample; returns the index of the first accepted sample (the samples of a
        message are strictly increasing in seq and t, so only a prefix can be refused)."""
        t, seq = a.t, a.seq
        n = len(t)
        j0 = 0
        if st.last_t is not None:
            j0 = int(np.searchsorted(t, st.last_t, side="right"))
            for j in range(j0):
                sj, tj = int(seq[j]), float(t[j])
                why = "duplicate" if sj == st.last_seq or tj == st.last_t else "out_of_order"
                st.count_bad(why)
                self.bad_log.warning(
                    st.name, "%s sample from %s: seq %d t %.6f after t %.6f",
                    why, st.name, sj, tj, st.last_t,
                )  # fmt: skip
        if j0 >= n:
            return n
        s0 = int(seq[j0])
        if st.last_seq is not None:
            if s0 > st.last_seq + 1:
                st.gaps += s0 - st.last_seq - 1
            elif s0 <= st.last_seq:
                st.restarts += 1
                self._service_event(st, "restart", float(t[j0]), value=s0)
        st.gaps += int(seq[n - 1]) - s0 - (n - 1 - j0)  # holes inside the message
        st.last_seq, st.last_t = int(seq[n - 1]), float(t[n - 1])
        st.samples += n - j0
        return j0

    def _update_dicts(self, parts: list) -> None:
        """Monitors without an array entry point (``monitor_factory``): one dict per sample."""
        batch: list[tuple[str, dict]] = []
        owners: list[tuple[ActuatorState, float]] = []
        for st, key, a, j0, t_recv in parts:
            for j in range(j0, len(a.t)):
                batch.append((key, _meas_dict(a, j)))
                owners.append((st, t_recv))
        outs = self.monitors.update_many(batch)
        now_m, now_w = time.monotonic(), time.time()
        for out, (st, t_recv) in zip(outs, owners, strict=True):
            if out is not None:
                self._handle_output(st, out, now_m - t_recv, now_w)

    def _update_arrays(self, parts: list) -> None:
        """The tick's samples in one ``MonitorBank.update_arrays`` call; outputs logged as
        blocks per actuator (est and residual every ``log_every``-th output, health every
        ``publish_every``-th, all three at an event), published every ``publish_every``-th."""
        from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS

        bank = self.monitors.bank
        sizes = [len(a.t) - j0 for _, _, a, j0, _ in parts]
        rows_of = [bank.index_of(key) for _, key, _, _, _ in parts]
        ks = np.repeat(np.array(rows_of, np.int64), sizes)
        t = np.concatenate([a.t[j0:] for _, _, a, j0, _ in parts])
        ch = np.concatenate([a.values[j0:] for _, _, a, j0, _ in parts])
        recv = np.repeat(np.array([p[4] for p in parts]), sizes)
        rows = bank.update_arrays(ks, t, ch)
        idx = rows.index
        if len(idx) == 0:
            return
        now_m, now_w = time.monotonic(), time.time()
        self.latency.extend((now_m - recv[idx]).tolist())
        old = rows.t > 1e9  # Unix-time sample clock: end-to-end age is meaningful
        if old.any():
            self.age.extend((now_w - rows.t[old]).tolist())
        has_ev = rows.events.flags()
        owner = ks[idx]
        states = {row: st for row, (st, *_rest) in zip(rows_of, parts, strict=True)}
        order = np.argsort(owner, kind="stable")
        bounds = np.flatnonzero(np.diff(owner[order])) + 1
        lg = self.logger
        log_block = getattr(lg, "log_block", None)
        for g in np.split(order, bounds):
            st = states[int(owner[g[0]])]
            n0 = st.outputs
            num = n0 + 1 + np.arange(len(g))
            ev = has_ev[g]
            pub = num % self.publish_every == 0
            base = f"/fleet/{st.aircraft}/{st.actuator}/"
            sel_log = g[(num % self.log_every == 0) | ev]
            sel_h = g[pub | ev]
            if log_block is not None:
                tl = rows.t
                if len(sel_log):
                    log_block(base + "est", tl[sel_log], EST_KEYS, rows.est[sel_log])
                    log_block(base + "residual", tl[sel_log], RES_KEYS, rows.res[sel_log])
                if len(sel_h):
                    log_block(base + "health", tl[sel_h], HEALTH_KEYS, rows.health[sel_h])
            else:
                for r in sel_log.tolist():
                    o = rows.output(r)
                    lg.log(base + "est", o.t, flat(o.est))
                    lg.log(base + "residual", o.t, flat(o.res))
                for r in sel_h.tolist():
                    o = rows.output(r)
                    lg.log(base + "health", o.t, flat(o.health))
            for r in g[ev].tolist():
                self._handle_events(st, base, float(rows.t[r]), rows.events[r])
            st.outputs = n0 + len(g)
            st.lazy = (rows, int(g[-1]))
            if self._session is not None:
                for r in g[pub].tolist():
                    o = rows.output(r)
                    self._publish(st, o.t, o.est, o.res, o.health)

    def _handle_events(self, st: ActuatorState, base: str, t: float, events: list) -> None:
        for ev in events:
            d = event_dict(ev)
            self.logger.log(base + "events", float(d.get("t") or t), flat(d))
            kind = str(d.get("kind"))
            if _is_active(d.get("state")):
                st.alarms[kind] = d
            else:
                st.alarms.pop(kind, None)
            st.events.append(d)
            log.info("alarm %s %s: %s", st.name, kind, d)

    def _handle_output(self, st: ActuatorState, out: Any, latency: float, now_w: float) -> None:
        t, est, res, health, events = _output_parts(out)
        st.outputs += 1
        st.est = est
        st.health = health
        self.latency.append(latency)
        if t > 1e9:  # Unix-time sample clock: end-to-end age is meaningful
            self.age.append(now_w - t)
        lg = self.logger
        base = f"/fleet/{st.aircraft}/{st.actuator}/"
        n = st.outputs
        if events or n % self.log_every == 0:
            lg.log(base + "est", t, flat(est))
            lg.log(base + "residual", t, flat(res))
        if events or n % self.publish_every == 0:
            lg.log(base + "health", t, flat(health))
        self._handle_events(st, base, t, events)
        if n % self.publish_every == 0 and self._session is not None:
            self._publish(st, t, est, res, health)

    def _publish(self, st: ActuatorState, t: float, est: dict, res: dict, health: dict) -> None:
        for tmpl, leaf, d in (
            (m.KEY_EST, "est", est),
            (m.KEY_RES, "res", res),
            (m.KEY_HEALTH, "health", health),
        ):
            k = (st.name, leaf)
            pub = self._publishers.get(k)
            if pub is None:
                pub = self._session.declare_publisher(
                    tmpl.format(aircraft=st.aircraft, actuator=st.actuator)
                )
                self._publishers[k] = pub
            try:
                try:  # the monitor's outputs are finite floats: plain json.dumps
                    payload = m.encode_json({"t": t, **d})
                except ValueError:
                    payload = m.encode_json({"t": t, **jsonable(d)})
                pub.put(payload)
            except Exception as e:
                self.errors += 1
                self.bad_log.warning("publish", "publish failed: %s", e)
        st.published += 1

    def _service_event(
        self, st: ActuatorState, kind: str, t: float | None, value: Any = None
    ) -> None:
        """A daemon-side event (silent, resumed, restart) in the log and the status."""
        t = float(t) if t is not None else time.time()
        d = {"t": t, "kind": kind, "value": value, "wall": time.time()}
        st.events.append(d)
        self.logger.log(f"/fleet/{st.aircraft}/{st.actuator}/service", t, flat(d))
        log.info("%s %s", st.name, kind)

    def check_silence(self, now: float | None = None) -> list[str]:
        """Mark actuators silent after ``silence_s`` without a message; return new ones."""
        now = time.monotonic() if now is None else now
        out = []
        for key, st in list(self.actuators.items()):
            last = self._arrival.get(key, st.last_recv)
            if not st.silent and last is not None and now - last > self.silence_s:
                st.silent = True
                out.append(st.name)
                self._service_event(st, "silent", st.last_t, value=now - last)
        return out

    def _run_worker(self) -> None:
        while True:
            stopping = self._stop.is_set()
            self._wake.wait(self.tick_s)
            self._wake.clear()
            try:
                self.process_pending()
                now = time.monotonic()
                if now - self._last_silence_check > 0.2:
                    self._last_silence_check = now
                    if self.check_silence(now):
                        commit = getattr(self.logger, "commit", None)
                        if commit is not None:
                            commit()
                if self._wd_interval is not None and now - self._wd_last > self._wd_interval:
                    self._wd_last = now
                    with self._notify_lock:  # never a WATCHDOG after STOPPING
                        if not self._stop.is_set():
                            sd_notify("WATCHDOG=1")
            except Exception:
                self.errors += 1
                log.exception("worker tick failed")
            if stopping and not self._queue:
                return
            if self.gather_s > 0:
                time.sleep(self.gather_s)  # let the next tick's samples gather into one batch

    # -- status -------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """A JSON-ready snapshot: actuators, counters, latency, alarms, silent actuators."""
        now = time.monotonic()
        for attempt in range(5):  # the worker mutates counters meanwhile: retry a torn read
            try:
                with self._lock:
                    acts = {k: st.snapshot(now) for k, st in list(self.actuators.items())}
                for k, a in acts.items():
                    a["monitor"] = self.monitors.counters_of(k)
                lat, age = list(self.latency), list(self.age)
                break
            except RuntimeError:  # "changed size during iteration"
                if attempt == 4:
                    raise
                time.sleep(0.001)
        p50, p99 = percentiles(lat)
        a50, a99 = percentiles(age)
        up = time.time() - self.started
        return jsonable(
            {
                "station": self.station,
                "shard": self.shard,
                "key_expr": self.key_expr,
                "pid": os.getpid(),
                "uptime_s": up,
                "log": [str(p) for p in getattr(self.logger, "paths", [])],
                "queue": len(self._queue),
                "queue_high": self.queue_high,
                "queue_size": self.queue_size,
                "samples": sum(a["samples"] for a in acts.values()),
                "dropped": sum(a["dropped"] for a in acts.values())
                + self.unknown.get("dropped", 0),
                "bad": sum(a["bad_total"] for a in acts.values()),
                "unknown": dict(self.unknown),
                "errors": self.errors,
                "latency_ms": {
                    "p50": None if p50 is None else 1e3 * p50,
                    "p99": None if p99 is None else 1e3 * p99,
                    "n": len(self.latency),
                },
                "age_ms": {
                    "p50": None if a50 is None else 1e3 * a50,
                    "p99": None if a99 is None else 1e3 * a99,
                },
                "busy_fraction": self.busy_s / up if up > 0 else 0.0,
                "actuators": acts,
                "alarms": [
                    {"actuator": a["aircraft"] + "/" + a["actuator"], **al}
                    for a in acts.values()
                    for al in a["alarms"]
                ],
                "alive_tokens": sorted(k for k, v in self.alive_tokens.items() if v),
                "lost_tokens": sorted(k for k, v in self.alive_tokens.items() if not v),
                "silent": [
                    a["aircraft"] + "/" + a["actuator"] for a in acts.values() if a["silent"]
                ],
            }
        )

    def _on_alive(self, sample) -> None:
        """Liveliness token of an actuator appeared (PUT) or vanished (DELETE)."""
        try:
            import zenoh

            key = str(sample.key_expr)
            self.alive_tokens[key] = sample.kind == zenoh.SampleKind.PUT
        except Exception:
            self.errors += 1

    def _on_status_query(self, query) -> None:
        try:
            key = m.KEY_STATUS.format(station=self.station, shard=self.shard)
            query.reply(key, m.encode_json(self.status()))
        except Exception as e:
            self.errors += 1
            log.warning("status query failed: %s", e)

    # -- lifecycle ----------------------------------------------------------------------
    def start(self, session=None) -> None:
        """Declare Zenoh entities on ``session`` (if given) and start the worker thread."""
        if session is not None:
            self._session = session
            self._decl.append(session.declare_subscriber(self.key_expr, self._on_zenoh_sample))
            skey = m.KEY_STATUS.format(station=self.station, shard=self.shard)
            self._decl.append(session.declare_queryable(skey, self._on_status_query))
            self._decl.append(
                session.liveliness().declare_token(f"monitor/{self.station}/{self.shard}/alive")
            )
            try:  # actuators' liveliness tokens (virtual actuators hold one)
                self._decl.append(
                    session.liveliness().declare_subscriber(
                        m.KEY_ALIVE.format(aircraft="*", actuator="*"), self._on_alive, history=True
                    )
                )
            except Exception as e:  # an older zenoh without history: data silence still works
                log.warning("no liveliness subscriber: %s", e)
        warm = self.monitors.warm_up()
        if warm > 0.05:
            log.info("monitor warm-up (JIT) took %.2f s", warm)
        self._worker = threading.Thread(
            target=self._run_worker, name="servowatch-worker", daemon=True
        )
        self._worker.start()
        sd_notify("READY=1")
        log.info(
            "daemon %s/%s started on %s, logging to %s",
            self.station,
            self.shard,
            self.key_expr,
            self.log_path,
        )

    def stop(self, timeout: float = 30.0) -> dict[str, Any]:
        """Stop the inflow, process what is queued, finish the log. Idempotent.

        Returns the final status."""
        if self._closed:
            return self.status()
        with self._notify_lock:
            self._stop.set()
            sd_notify("STOPPING=1")
        # stop the inflow first: the subscriber goes, queued messages are still processed
        for d in self._decl[:1]:
            with contextlib.suppress(Exception):
                d.undeclare()
        self._wake.set()
        if self._worker is not None:
            self._worker.join(timeout)
        while self._queue:  # no worker (tests) or it gave up: drain here
            self.process_pending()
        for d in self._decl[1:]:
            with contextlib.suppress(Exception):
                d.undeclare()
        for pub in self._publishers.values():
            with contextlib.suppress(Exception):
                pub.undeclare()
        final = self.status()
        self.logger.close()
        self._closed = True
        log.info(
            "daemon stopped: %s samples, %s dropped, %s bad",
            final["samples"],
            final["dropped"],
            final["bad"],
        )
        return final

    def __enter__(self) -> Daemon:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _reason(e: m.MessageError, payload: bytes) -> str:
    """A short counter name for a decoding failure."""
    f = (e.field or "").split(".")[-1]
    text = str(e)
    if f == "payload" and "exceeds max_bytes" in text:
        return "oversize"
    if "finite" in text:
        return "non_finite"
    if "not increasing" in text:
        return "out_of_order"
    if f == "payload" and "JSON" in text:
        return "malformed"
    if f in ("header", "n", "version", "kind", "payload"):
        return "malformed"
    return "schema"


def _load_baseline(path: Any) -> Any:
    """The calibration baseline at ``path`` (service.monitor's loader), or None."""
    if not path:
        return None
    from service import monitor as mon

    for name in ("load_baseline", "Baseline.load"):
        obj: Any = mon
        for part in name.split("."):
            obj = getattr(obj, part, None)
            if obj is None:
                break
        if obj is not None:
            return obj(path)
    raise RuntimeError(f"baseline {path}: service.monitor has no baseline loader")
