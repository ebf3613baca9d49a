"""``servowatch demo``: router, virtual actuator, leak injection and daemon, live, in one command.

No server and no file needed. The demo opens a Zenoh router on a free loopback port (in this
process), starts the monitoring daemon (this process, its own client session and worker
thread) and a virtual actuator (a child process: ``servowatch actuator`` on the demo duty
cycle, ``scenarios/demo.toml``), injects a leakage fault after a few seconds through the
actuator's ``@fault`` queryable, shows the estimates and alarms live, and ends with a summary,
``demo.mcap`` and a plot (``demo.png``).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from service.cli.util import EXIT_IO, check_outputs, emit_json, fail, finite_float

NAME = "demo"
HELP = "Self-contained live demo: router, virtual actuator with a leak, daemon, MCAP, plot."

AIRCRAFT = "AC001"
ACTUATOR = "elevator_L"
# ``servowatch actuator`` without the dispatcher (which imports every command module)
_ACTUATOR_MAIN = (
    "import argparse, sys; from service.cli.commands import actuator as a; "
    "p = argparse.ArgumentParser(); a.add_arguments(p); sys.exit(a.run(p.parse_args()))"
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--duration", type=finite_float, default=15.0, help="actuator run time [s] (default 15)"
    )
    p.add_argument(
        "--inject-at", type=finite_float, default=5.0, help="leak injection time [s] (default 5)"
    )
    p.add_argument(
        "--leak",
        type=finite_float,
        default=8e-13,
        help="injected leakage coefficient c_lk [m^3/s/Pa] (default 8e-13, 4x)",
    )
    p.add_argument("--ramp-s", type=finite_float, default=0.0, help="leak ramp time [s]")
    p.add_argument(
        "--rate",
        type=finite_float,
        default=1000.0,
        help="actuator sample rate [Hz] (default 1000)",
    )
    p.add_argument("--scenario", default="demo", help="actuator scenario (default demo)")
    p.add_argument("--out", default="demo.mcap", help="MCAP log (default demo.mcap)")
    p.add_argument("--plot", default="demo.png", help="PNG plot (default demo.png; '' = none)")
    p.add_argument(
        "--foxglove", default=None, metavar="HOST:PORT",
        help="also serve the channels live over the Foxglove WebSocket protocol (loopback; "
        "one row in 10 per topic, events all)",
    )  # fmt: skip
    p.add_argument("--lines", action="store_true", help="line updates even on a terminal")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")


# --------------------------------------------------------------------------- live view


def _fmt(v: Any, spec: str = ".3g") -> str:
    return "-" if not isinstance(v, int | float) else format(v, spec)


def _view(st: dict, t_run: float, args, fault: dict | None) -> list[str]:
    acts = st.get("actuators", {})
    a = next(iter(acts.values()), None)
    lat = st.get("latency_ms", {})
    lines = [
        f"servowatch demo  {AIRCRAFT}/{ACTUATOR}  virtual HF actuator '{args.scenario}' at "
        f"{args.rate:g} Hz   t = {t_run:5.1f} / {args.duration:g} s",
    ]
    if fault is None:
        lines.append(f"fault: none yet (leak c_lk -> {args.leak:.3g} at t = {args.inject_at:g} s)")
    else:
        lines.append(f"fault: {fault.get('message')} at t = {fault.get('t_run', 0):.1f} s")
    lines.append(
        f"samples {st.get('samples', 0)}  dropped {st.get('dropped', 0)}  bad {st.get('bad', 0)}"
        f"  queue {st.get('queue', 0)}  latency p50 {_fmt(lat.get('p50'))} ms"
        f"  p99 {_fmt(lat.get('p99'))} ms"
    )
    if a is None:
        lines.append("waiting for the actuator ...")
        return lines
    e, h = a.get("est", {}), a.get("health", {})
    lines.append(
        f"estimates: c_lk {_fmt(e.get('c_lk'))} +- {_fmt(e.get('c_lk_sigma'), '.2g')} m^3/s/Pa"
        f"   P_SR {_fmt((e.get('p_sr') or 0) / 1e6)} MPa   F_R {_fmt((e.get('f_r') or 0) / 1e3)}"
        f" kN   x_J {_fmt((e.get('x_j') or 0) * 1e3)} mm"
    )
    alarms = [x.get("kind") for x in a.get("alarms", [])]
    flag = ("ALARM: " + ", ".join(map(str, alarms))) if alarms else "no alarm"
    lines.append(
        f"health: leak ratio {_fmt(h.get('leak_ratio'))}   supply ratio "
        f"{_fmt(h.get('supply_ratio'))}   NIS {_fmt(h.get('nis_avg'))}   {flag}"
        + ("   SILENT" if a.get("silent") else "")
    )
    for ev in list(a.get("events", []))[-4:]:
        lines.append(
            f"  event t={_fmt(ev.get('t', 0) - st.get('_t0', 0), '.2f')} s  {ev.get('kind')} "
            f"{ev.get('state', '')} {_fmt(ev.get('value'))}"
        )
    return lines


class _Screen:
    """ANSI redraw on a terminal, a line per second otherwise."""

    def __init__(self, tty: bool, stream=None):
        self.tty = tty
        self.stream = stream or sys.stdout
        self.n = 0
        self.last = 0.0

    def show(self, lines: list[str]) -> None:
        if self.tty:
            out = (f"\x1b[{self.n}F" if self.n else "") + "".join(
                "\x1b[2K" + ln + "\n" for ln in lines
            )
            if len(lines) < self.n:
                out += "\x1b[2K\n" * (self.n - len(lines))
                out += f"\x1b[{self.n - len(lines)}F"
            sys.stdout.write(out)
            sys.stdout.flush()
            self.n = len(lines)
        elif time.monotonic() - self.last >= 1.0:
            self.last = time.monotonic()
            print(" | ".join(lines[:1] + lines[2:5]), file=self.stream, flush=True)


# --------------------------------------------------------------------------- plot


def plot_demo(log_path: Path, png: Path, t_inject: float | None, c_true: float | None) -> int:
    """Plot c_lk, leak ratio and jack position from the demo log; return messages read."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from models.params import EHAParams
    from service.log.blocks import read_blocks

    base = f"/fleet/{AIRCRAFT}/{ACTUATOR}/"
    # the fields of each series, read as arrays by the compiled reader
    fields = {"est": ("c_lk", "c_lk_sigma"), "health": ("leak_ratio", "alarm_leak"),
              "meas": ("x_cmd", "x_j")}  # fmt: skip
    parts: dict[str, list] = {k: [] for k in fields}
    n = 0
    for b in read_blocks(log_path, topics=[base + k for k in fields]):
        kind = b.topic[len(base) :]
        cols = [b.values[:, b.names.index(f)] if f in b.names else np.full(len(b.t), np.nan)
                for f in fields[kind]]  # fmt: skip
        parts[kind].append(np.column_stack([b.t, *cols]))
        n += len(b.t)
    E, H, M = (np.concatenate(parts[k]) if parts[k] else np.empty((0, 3)) for k in fields)
    if not len(E):
        return n
    M = M[::5]
    t0 = min(E[0, 0], M[0, 0]) if len(M) else E[0, 0]
    for a in (E, H, M):
        a[:, 0] -= t0
    H[:, 2] = np.nan_to_num(H[:, 2])  # an alarm flag absent: off
    fig, ax = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    ax[0].plot(E[:, 0], E[:, 1], lw=0.8, label="estimated $C_{Lk}$")
    ax[0].fill_between(
        E[:, 0], E[:, 1] - 2 * E[:, 2], E[:, 1] + 2 * E[:, 2], alpha=0.2, label="$\\pm 2\\sigma$"
    )
    if t_inject is not None and c_true is not None:
        tt = t_inject - t0
        c0 = EHAParams().c_lk
        ax[0].step(
            [0, tt, E[-1, 0]],
            [c0, c_true, c_true],
            where="post",
            color="k",
            lw=1,
            ls="--",
            label="injected (truth)",
        )
    ax[0].set_ylabel("$C_{Lk}$ [m$^3$/s/Pa]")
    ax[0].legend(loc="upper left", fontsize=8)
    ax[1].plot(H[:, 0], H[:, 1], lw=0.8, label="leak ratio $C_{Lk}/C_{Lk,0}$")
    ax[1].fill_between(
        H[:, 0],
        0,
        np.nanmax(H[:, 1]) if len(H) else 1,
        where=H[:, 2] > 0,
        color="r",
        alpha=0.15,
        label="leak alarm",
    )
    ax[1].set_ylabel("leak ratio [-]")
    ax[1].legend(loc="upper left", fontsize=8)
    if len(M):
        ax[2].plot(M[:, 0], M[:, 1] * 1e3, lw=0.8, label="$x_{cmd}$")
        ax[2].plot(M[:, 0], M[:, 2] * 1e3, lw=0.8, label="$x_J$ measured")
    ax[2].set_ylabel("position [mm]")
    ax[2].set_xlabel("time [s]")
    ax[2].legend(loc="upper left", fontsize=8)
    for a in ax:
        if t_inject is not None:
            a.axvline(t_inject - t0, color="k", lw=0.6, ls=":")
        a.grid(alpha=0.3)
    fig.suptitle(
        f"servowatch demo: {AIRCRAFT}/{ACTUATOR}, leak injected at {(t_inject or t0) - t0:.1f} s"
    )
    fig.tight_layout()
    from service.plots import save_png

    try:
        save_png(fig, png, 110)
    finally:
        plt.close(fig)
    return n


# --------------------------------------------------------------------------- run


_INJECT_TRIES = 5


def run(args: argparse.Namespace) -> int:
    import zenoh

    from service.cli.commands.inject import send_fault
    from service.config import FoxgloveSettings, ServiceConfig, ZenohSettings
    from service.daemon import Daemon
    from service.sim.scenarios import ScenarioError, resolve_scenario
    from service.wire import messages as msgs
    from service.zenoh_util import free_port, loopback, make_config

    if not (args.duration > 0 and 0 <= args.inject_at < args.duration and args.rate > 0):
        return fail("need --duration > 0, 0 <= --inject-at < --duration, --rate > 0")
    if args.duration > 50:
        print(
            "note: a --duration above 50 s makes the demo last more than a minute", file=sys.stderr
        )
    try:
        scenario = str(resolve_scenario(args.scenario))
    except ScenarioError as e:
        return fail(str(e))
    check_outputs([("--out", args.out), ("--plot", args.plot or None)], [("--scenario", scenario)])
    try:
        fx = None if args.foxglove is None else FoxgloveSettings(listen=args.foxglove)
    except ValueError as e:
        return fail(f"--foxglove: {e}")
    from service.cli.warmup import ensure

    ensure("models", "monitor", "log")  # a first run compiles here, and says so
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.is_file() and not out.is_symlink():  # a new log (never a device's node)
        out.unlink()
    ep = loopback(free_port())
    cfg = ServiceConfig(
        station="demo",
        shard="0",
        rotate_bytes=None,
        rotate_s=None,
        publish_every=10,
        silence_s=2.0,
        zenoh=ZenohSettings(mode="client", connect=[ep]),
        foxglove=fx,
    )
    tty = sys.stdout.isatty() and not args.lines and not args.json
    screen = _Screen(tty, sys.stderr if args.json else sys.stdout)
    err_log = tempfile.NamedTemporaryFile(  # noqa: SIM115 (closed after the child exits)
        "w+", prefix="servowatch-demo-actuator-", suffix=".log", delete=False
    )
    proc: subprocess.Popen | None = None
    fault: dict | None = None
    t_inject_sample: float | None = None
    inject_tries = 0
    final: dict = {}
    t_start_wall = time.time()
    router = zenoh.open(make_config("router", [ep]))
    try:
        session = zenoh.open(cfg.zenoh.to_zenoh())
        daemon = Daemon(cfg, log_path=out)
        try:
            daemon.start(session)
            cmd = [
                sys.executable,
                "-c",
                _ACTUATOR_MAIN,
                "--connect",
                ep,
                "--scenario",
                scenario,
                "--aircraft",
                AIRCRAFT,
                "--actuator",
                ACTUATOR,
                "--rate",
                f"{args.rate:g}",
                "--duration",
                f"{args.duration:g}",
            ]
            proc = subprocess.Popen(
                cmd,
                stdout=subprocess.DEVNULL,
                stderr=err_log,
                env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )
            t0 = time.monotonic()
            deadline = t0 + args.duration + 20.0  # the actuator needs a few s to start
            t_first: float | None = None
            t0_sample: float | None = None
            while time.monotonic() < deadline:
                st = daemon.status()
                a = next(iter(st["actuators"].values()), None)
                if t_first is None:  # first message received (not processed: the demo
                    # clock follows the actuator even while the daemon is catching up)
                    t_first = next(iter(daemon.intake.first_arrival.values()), None)
                t_run = 0.0 if t_first is None else time.monotonic() - t_first
                if fault is None and t_first is not None and t_run >= args.inject_at:
                    ack = send_fault(
                        session,
                        AIRCRAFT,
                        ACTUATOR,
                        msgs.FaultCommand(kind="leak", value=args.leak, ramp_s=args.ramp_s),
                        timeout=3.0,
                    )
                    inject_tries += 1
                    if ack is None and inject_tries < _INJECT_TRIES:
                        # a loaded machine can delay the answer: ask again (the actuator
                        # applies a repeated leak command idempotently)
                        print(
                            f"note: no answer to the fault command yet (try {inject_tries})",
                            file=sys.stderr,
                        )
                        continue
                    fault = {
                        "ok": bool(ack and ack.ok),
                        "t_run": t_run,
                        "message": ack.message if ack else "no answer from the actuator",
                    }
                    t_inject_sample = next(
                        (x.get("t_ack") for x in (ack.active if ack else []) if "t_ack" in x),
                        (a or {}).get("last_t"),
                    )
                if a is not None and t0_sample is None and a.get("last_t") is not None:
                    # sample clock at the first sample (the actuator counts from seq 0)
                    t0_sample = a["last_t"] - a["last_seq"] / args.rate
                st["_t0"] = t0_sample or 0.0
                screen.show(_view(st, t_run, args, fault))
                if proc.poll() is not None:
                    break
                time.sleep(0.25)
            if proc.poll() is None:
                proc.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(5)
            # let the daemon catch up with what it has received (bounded), then finish
            t_end = time.monotonic() + 15.0
            while daemon.status()["queue"] and time.monotonic() < t_end:
                time.sleep(0.1)
            final = daemon.stop()
        finally:
            daemon.stop()
            session.close()
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
        router.close()
    err_log.seek(0)
    act_err = err_log.read()
    err_log.close()
    with contextlib.suppress(OSError):
        os.unlink(err_log.name)
    if tty:
        sys.stdout.write("\n")
    a = next(iter(final.get("actuators", {}).values()), None)
    if a is None:
        return fail("the virtual actuator published nothing; its log:\n" + act_err[-2000:], 1)
    log_failure = final.get("log_failure")
    png = None
    if args.plot and not log_failure:
        png = Path(args.plot)
        try:
            plot_demo(out, png, t_inject_sample, args.leak if fault and fault["ok"] else None)
        except Exception as e:  # the summary still stands without a plot
            print(f"servowatch demo: plot failed: {e}", file=sys.stderr)
            png = None
    leak_events = [e for e in a.get("events", []) if e.get("kind") == "leak"]
    first_raise = next(
        (
            e
            for e in ([] if log_failure else final_events(out))
            if e[1] == "leak"
            and e[2] == "raised"
            and t_inject_sample is not None
            and e[0] >= t_inject_sample
        ),
        None,
    )
    summary = {
        "log": str(out),
        "plot": str(png) if png else None,
        "samples": final["samples"],
        "dropped": final["dropped"],
        "bad": final["bad"],
        "latency_ms": final["latency_ms"],
        "fault": fault,
        "c_lk_final": a["est"].get("c_lk"),
        "c_lk_sigma_final": a["est"].get("c_lk_sigma"),
        "leak_ratio_final": a["health"].get("leak_ratio"),
        "alarms_active": [x.get("kind") for x in a.get("alarms", [])],
        "leak_detected_after_s": None if first_raise is None else first_raise[0] - t_inject_sample,
        "leak_events": len(leak_events),
        "wall_s": time.time() - t_start_wall,
        "log_failure": log_failure,
    }
    code = 0
    if log_failure:  # the daemon's rule (`servowatch run` exits 5): never a complete-looking log
        code = EXIT_IO
        print(f"servowatch: error: --out {out}: the MCAP log failed: {log_failure} (it holds "
              "only what was written before; no plot)", file=sys.stderr)  # fmt: skip
    if args.json:
        emit_json(summary)
        return code
    print("\nsummary")
    if log_failure:
        print(
            f"  log            {summary['log']} FAILED: {log_failure} ({summary['samples']} "
            "samples received, the log holds only those written before the failure)"
        )
    else:
        print(
            f"  log            {summary['log']} ({summary['samples']} samples logged, "
            f"{summary['dropped']} dropped, {summary['bad']} bad)"
        )
    print(f"  plot           {summary['plot']}")
    print(f"  fault          {fault['message'] if fault else 'not injected'}")
    print(
        f"  final c_lk     {_fmt(summary['c_lk_final'])} +- "
        f"{_fmt(summary['c_lk_sigma_final'], '.2g')} m^3/s/Pa (injected {args.leak:.3g})"
    )
    print(
        f"  leak ratio     {_fmt(summary['leak_ratio_final'])}; alarms active: "
        f"{', '.join(summary['alarms_active']) or 'none'}"
    )
    det = summary["leak_detected_after_s"]
    print(
        "  leak alarm     "
        + (
            "not raised after the injection"
            if det is None
            else f"raised {det:.2f} s after the injection"
        )
    )
    lat = summary["latency_ms"]
    print(
        f"  latency        sample receipt -> health p50 {_fmt(lat.get('p50'))} ms, "
        f"p99 {_fmt(lat.get('p99'))} ms"
    )
    print(f"  wall time      {summary['wall_s']:.1f} s")
    return code


def final_events(path: Path) -> list[tuple[float, str, str]]:
    """(t, kind, state) of every alarm event in a daemon log."""
    from service.log import read_log

    out = []
    for _, t, msg in read_log(path, match=lambda topic: topic.endswith("/events")):
        out.append((t, str(msg.get("kind")), str(msg.get("state"))))
    return out
