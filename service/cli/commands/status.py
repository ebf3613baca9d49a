"""``servowatch status``: query every reachable daemon's status queryable."""

from __future__ import annotations

import argparse
import math

from service.cli.util import emit_json
from service.edge.fleet import rul_interval
from service.edge.status import query_status

NAME = "status"
HELP = "Query the status of every monitoring daemon reachable on Zenoh."


def add_arguments(p: argparse.ArgumentParser) -> None:
    from service.cli.args import add_zenoh_arguments

    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--timeout", type=float, default=2.0, help="reply timeout [s]")
    add_zenoh_arguments(p)


def _fmt(v, spec: str = ".3g") -> str:
    return "-" if v is None else format(v, spec)


def _num(v) -> float | None:
    """``v`` as a finite float, else None (a status field may be null, absent or NaN)."""
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        return None
    return float(v)


def _pct(v) -> str:
    n = _num(v)
    return "-" if n is None else f"{100.0 * n:.0f} %"


def format_rul(rul: dict | None) -> str:
    """A stored RUL on its history's own axis: ``RUL 42 flights [5-80] ~12 d`` (a history
    that counts flights: flights, its 90 % interval and calendar days where known), ``RUL
    120 h [30-400]`` (operating hours), ``RUL - (insufficient history)``, ``RUL none
    predicted``, or ``RUL -`` without one."""
    iv = rul_interval(rul if isinstance(rul, dict) else None)
    if iv is None:
        return "RUL -"
    med = iv["median"]
    if med is None:
        why = rul.get("status")
        if why == "insufficient history":
            return "RUL - (insufficient history)"
        return "RUL none predicted" if rul.get("periods") else "RUL -"
    unit = ("flight" if round(med) == 1 else "flights") if iv["unit"] == "flights" else "h"
    text = f"RUL {med:.0f} {unit} [{_fmt(iv['lo'], '.0f')}-{_fmt(iv['hi'], '.0f')}]"
    if iv["unit"] == "flights" and iv["median_days"] is not None:
        text += f" ~{iv['median_days']:.0f} d"
    return text


def format_unit(a: dict) -> list[str]:
    """The lines of one unit of a daemon's status, every value chosen by name (a model that
    adds or reorders estimate fields changes nothing here): counters; C_Lk with its
    1-sigma [m^3/(s Pa)], the leak and supply ratios over the baseline, the NIS in band;
    then silence, active alarms, commissioning and baseline version, periods and RUL."""
    est = a.get("est") if isinstance(a.get("est"), dict) else {}
    health = a.get("health") if isinstance(a.get("health"), dict) else {}
    c_lk, c_sig = _num(est.get("c_lk")), _num(est.get("c_lk_sigma"))
    head = (
        f"  {a.get('aircraft')}/{a.get('actuator')}: {a.get('samples')} samples, "
        f"dropped {a.get('dropped')}, gaps {a.get('gaps')}, bad {a.get('bad_total', 0)}"
    )
    ind = (
        f"    C_Lk {_fmt(c_lk)} +- {_fmt(c_sig, '.2g')} m^3/(s Pa), "
        f"leak ratio {_fmt(_num(health.get('leak_ratio')))}, "
        f"supply ratio {_fmt(_num(health.get('supply_ratio')))}, "
        f"NIS in band {_pct(a.get('nis_in_band'))}"
    )
    flags = []
    if a.get("silent"):
        flags.append("SILENT")
    alarms = [x for x in a.get("alarms") or [] if isinstance(x, dict)]
    if alarms:
        flags.append(
            "ALARM " + ", ".join(f"{x.get('kind')} ({_fmt(_num(x.get('value')))})" for x in alarms)
        )
    else:
        flags.append("no alarm")
    if a.get("commissioned") is False:
        flags.append("NOT COMMISSIONED (default baseline)")
    elif a.get("commissioned"):
        flags.append(f"commissioned, baseline v{a.get('baseline_version')}")
    if "periods" in a:
        flags.append(f"{plural(a['periods'], 'period')}, {format_rul(a.get('rul'))}")
    return [head, ind, "    " + "; ".join(flags)]


def _size(n) -> str:
    """Bytes in binary units: ``512 B``, ``3.2 MiB``, ``50 GiB``."""
    v = _num(n)
    if v is None:
        return "-"
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(v) < 1024 or unit == "TiB":
            return f"{v:.0f} {unit}" if unit == "B" or v == int(v) else f"{v:.1f} {unit}"
        v /= 1024
    return "-"


def plural(n, one: str, many: str | None = None) -> str:
    """``1 period``, ``3 periods``, ``- periods`` (``many``: the plural when not ``one + s``)."""
    word = one if n == 1 else (many or one + "s")
    return f"{'-' if n is None else n} {word}"


def format_log(st: dict) -> list[str]:
    """The daemon's log file now written, its retention (limits, kept, deleted, the last
    deleted file) and the store it writes: one line each."""
    out = []
    paths = st.get("log") if isinstance(st.get("log"), list) else []
    ret = st.get("log_retention") if isinstance(st.get("log_retention"), dict) else None
    if paths:
        text = f"  log {paths[-1]}"
        if ret is not None:
            lim = [
                f"{_size(ret.get('keep_bytes'))}" if ret.get("keep_bytes") else None,
                f"{_fmt(_num(ret.get('keep_days')), 'g')} d" if ret.get("keep_days") else None,
            ]
            text += (
                f"; keeps {' and '.join(x for x in lim if x) or 'everything'}: "
                f"{plural(ret.get('kept_files'), 'file')} ({_size(ret.get('kept_bytes'))}) kept, "
                f"{plural(ret.get('deleted_files'), 'file')} ({_size(ret.get('deleted_bytes'))}) "
                "deleted"
            )  # fmt: skip
            last = ret.get("last_deleted") or []
            if last and isinstance(last[-1], dict):
                text += f", the last {last[-1].get('path')} (ended {last[-1].get('end')})"
        out.append(text)
    store = st.get("store")
    out.append(f"  store {store.get('where')}" if isinstance(store, dict) else "  store: none")
    return out


def format_status(daemons: dict) -> str:
    """Human-readable table of the daemons' status."""
    lines = []
    for key, st in sorted(daemons.items()):
        if not isinstance(st, dict) or "malformed" in st or "error" in st:
            why = st.get("malformed") or st.get("error") if isinstance(st, dict) else st
            lines.append(f"{key!r}: MALFORMED reply ({why}), ignored")
            continue
        if "name_mismatch" in st:  # the key's name is the replier's (its certificate's)
            lines.append(
                f"{key}: NAME MISMATCH: the reply claims {st['name_mismatch']!r}; "
                "its units are not believed"
            )
            continue
        lat = st.get("latency_ms") or {}
        lines.append(
            f"{key}: pid {st.get('pid')} up {_fmt(st.get('uptime_s'), '.0f')} s, "
            f"model {st.get('model') or '-'}, "
            f"{st.get('samples')} samples, {st.get('dropped')} dropped, {st.get('bad')} bad, "
            f"latency p50 {_fmt(lat.get('p50'))} ms p99 {_fmt(lat.get('p99'))} ms"
        )
        if st.get("log_failure"):
            lines.append(f"  DEGRADED: the MCAP log failed: {st['log_failure']}")
        lines.extend(format_log(st))
        g = st.get("group")
        if g:
            lines.append(
                f"  group {g.get('name')}: members {', '.join(g.get('members') or [])}"
                f"{'' if g.get('joined') else ' (joining)'}; {g.get('takeovers')} units taken "
                f"over, {g.get('released')} released, {g.get('held_units')} held"
            )
            for unit, u in sorted((g.get("unmonitored") or {}).items()):
                lines.append(
                    f"  UNMONITORED {unit}: no member's health output for more than "
                    f"{_fmt(g.get('unmonitored_s'), 'g')} s (owner: {u.get('owner') or '-'})"
                )
        fx = st.get("foxglove")
        if fx:
            gd = fx.get("guard") or {}
            mem = (
                f", {gd.get('connections')}/{gd.get('max_connections')} viewers, "
                f"{_fmt((gd.get('buffered_bytes') or 0) / 2**20, '.1f')} of "
                f"{_fmt((gd.get('memory_bound_bytes') or 0) / 2**20, '.0f')} MiB buffered"
                if gd
                else ""
            )
            lines.append(
                f"  foxglove ws://{fx.get('listen')}: {fx.get('subscribed_topics')} topics subscribed, "
                f"{fx.get('sent')} sent, {fx.get('dropped')} dropped{mem}"
            )
        if st.get("feed_failure"):
            lines.append(f"  DEGRADED: {st['feed_failure']}")
        for _name, a in sorted(st.get("actuators", {}).items()):
            lines.extend(format_unit(a))
    return "\n".join(lines) if lines else "no daemon answered"


def run(args: argparse.Namespace) -> int:

    from service.cli.args import open_zenoh_session, zenoh_config

    with open_zenoh_session(zenoh_config(args)) as session:
        daemons = query_status(session, args.timeout)
    if args.json:
        bad = sum(1 for v in daemons.values() if "malformed" in v or "name_mismatch" in v)
        emit_json({"daemons": daemons, "malformed": bad})
    else:
        print(format_status(daemons))
    return 0 if daemons else 3
