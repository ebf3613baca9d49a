"""``servowatch status``: query every reachable daemon's status queryable."""

from __future__ import annotations

import argparse
import math

from service.cli.util import emit_json, plural
from service.edge.fleet import condition_of, rul_interval
from service.edge.status import query_status

NAME = "status"
HELP = "Query the status of every monitoring daemon reachable on Zenoh."


def add_arguments(p: argparse.ArgumentParser) -> None:
    from service.cli.args import add_zenoh_arguments

    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--timeout", type=float, default=2.0, help="reply timeout [s]")
    add_zenoh_arguments(p)


def _fmt(v, spec: str = ".3g") -> str:
    """A number as ``spec``, ``-`` for anything else (None, a string, NaN: a reply is
    input, every field is checked where it is printed)."""
    n = _num(v)
    return "-" if n is None else format(n, spec)


def _s(v, limit: int = 200) -> str:
    """A reply's value shown on the terminal: its control characters escaped (a reply
    cannot move the cursor, clear the screen or forge a line), cut to ``limit``."""
    from service.log.escape import escape_controls

    return "-" if v is None else escape_controls(v, limit)


def _int(v) -> str:
    """A counter, ``-`` when it is not a number."""
    n = _num(v)
    return "-" if n is None else f"{n:.0f}"


def _strs(v) -> list[str]:
    """The strings of a list field (anything else left out), escaped."""
    return [_s(x, 80) for x in v if isinstance(x, str)] if isinstance(v, list) else []


def _dict(v) -> dict:
    return v if isinstance(v, dict) else {}


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
    try:
        iv = rul_interval(rul if isinstance(rul, dict) else None)
    except (TypeError, ValueError, KeyError):  # a reply's RUL of the wrong shape
        return "RUL ?"
    if iv is None:
        return "RUL -"
    med = _num(iv["median"])
    if med is None:
        why = rul.get("status")
        if why == "insufficient history":
            return "RUL - (insufficient history)"
        return "RUL none predicted" if rul.get("periods") else "RUL -"
    unit = ("flight" if round(med) == 1 else "flights") if iv["unit"] == "flights" else "h"
    text = f"RUL {med:.0f} {unit} [{_fmt(iv['lo'], '.0f')}-{_fmt(iv['hi'], '.0f')}]"
    if iv["unit"] == "flights" and _num(iv["median_days"]) is not None:
        text += f" ~{iv['median_days']:.0f} d"
    return text


def format_unit(a: dict) -> list[str]:
    """The lines of one unit of a daemon's status, every value chosen by name (a model that
    adds or reorders estimate fields changes nothing here): counters; C_Lk with its
    1-sigma [m^3/(s Pa)], the leak and supply ratios over the baseline, the NIS in band and
    the pooled C_Lk with its sigma where the daemon has one (decisions/0025); then silence, active alarms, commissioning and baseline version, periods and RUL."""
    est, health = _dict(a.get("est")), _dict(a.get("health"))
    c_lk, c_sig = _num(est.get("c_lk")), _num(est.get("c_lk_sigma"))
    head = (
        f"  {_s(a.get('aircraft'))}/{_s(a.get('actuator'))}: {_int(a.get('samples'))} samples, "
        f"dropped {_int(a.get('dropped'))}, gaps {_int(a.get('gaps'))}, "
        f"bad {_int(a.get('bad_total', 0))}"
    )
    ind = (
        f"    C_Lk {_fmt(c_lk)} +- {_fmt(c_sig, '.2g')} m^3/(s Pa), "
        f"leak ratio {_fmt(_num(health.get('leak_ratio')))}, "
        f"supply ratio {_fmt(_num(health.get('supply_ratio')))}, "
        f"NIS in band {_pct(a.get('nis_in_band'))}"
    )
    pooled = a.get("c_lk_pooled") if isinstance(a.get("c_lk_pooled"), dict) else None
    if "c_lk_pooled" in a:  # the pooled C_Lk (issue 51, 0025; shown, not the indicator)
        ind += (
            f", pooled {_fmt(_num(pooled.get('value')))} +- "
            f"{_fmt(_num(pooled.get('sigma')), '.2g')}"
            if pooled
            else ", pooled abstains"
        )
    flags = []
    if a.get("silent"):
        flags.append("SILENT")
    alarms = [x for x in a.get("alarms") or [] if isinstance(x, dict)]
    if alarms:
        flags.append(
            "ALARM "
            + ", ".join(f"{_s(x.get('kind'), 40)} ({_fmt(x.get('value'))})" for x in alarms)
        )
    else:
        flags.append("no alarm")
    if a.get("commissioned") is False:
        flags.append("NOT COMMISSIONED (default baseline)")
    elif a.get("commissioned"):
        flags.append(f"commissioned, baseline v{_int(a.get('baseline_version'))}")
    if "periods" in a:
        flags.append(f"{plural(_num(a['periods']), 'period')}, {format_rul(a.get('rul'))}")
        cond, why = condition_of(a)
        if cond == "failed":
            flags.append(f"FAILED: {why}")
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


def format_log(st: dict) -> list[str]:
    """The daemon's log file now written, its retention (limits, kept, deleted, the last
    deleted file) and the store it writes: one line each."""
    out = []
    paths = st.get("log") if isinstance(st.get("log"), list) else []
    ret = st.get("log_retention") if isinstance(st.get("log_retention"), dict) else None
    if paths:
        text = f"  log {_s(paths[-1], 300)}"
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
                text += (f", the last {_s(last[-1].get('path'), 300)} "
                         f"(ended {_s(last[-1].get('end'), 40)})")  # fmt: skip
        out.append(text)
    store = st.get("store")
    out.append(f"  store {_s(store.get('where'), 300)}" if isinstance(store, dict) else
               "  store: none")  # fmt: skip
    return out


def format_status(daemons: dict) -> str:
    """Human-readable table of the daemons' status: every field checked as it is printed
    (``-`` for one that is not what it should be), every string escaped, the fields and
    units the reply check left out named (``BAD FIELD``, ``BAD UNIT``)."""
    lines = []
    for key, st in sorted(daemons.items()):
        if not isinstance(st, dict) or "malformed" in st or "error" in st:
            why = st.get("malformed") or st.get("error") if isinstance(st, dict) else st
            lines.append(f"{_s(repr(key))}: MALFORMED reply ({_s(why)}), ignored")
            continue
        if "name_mismatch" in st:  # the key's name is the replier's (its certificate's)
            lines.append(
                f"{_s(key)}: NAME MISMATCH: the reply claims {_s(repr(st['name_mismatch']))}; "
                "its units are not believed"
            )
            continue
        lat = _dict(st.get("latency_ms"))
        lines.append(
            f"{_s(key)}: pid {_int(st.get('pid'))} up {_fmt(st.get('uptime_s'), '.0f')} s, "
            f"model {_s(st.get('model') or '-', 40)}, "
            f"{_int(st.get('samples'))} samples, {_int(st.get('dropped'))} dropped, "
            f"{_int(st.get('bad'))} bad, "
            f"latency p50 {_fmt(lat.get('p50'))} ms p99 {_fmt(lat.get('p99'))} ms"
        )
        for f in st.get("bad_fields") or ():
            lines.append(f"  BAD FIELD {_s(f, 80)}: wrong type, not shown")
        for name, why in _dict(st.get("bad_units")).items():
            lines.append(f"  BAD UNIT {_s(repr(name), 100)}: {_s(why)}, not shown")
        more = (_num(st.get("bad_units_total")) or 0) - len(_dict(st.get("bad_units")))
        if more > 0:
            lines.append(f"  ... and {more:.0f} more bad units")
        if st.get("log_failure"):
            lines.append(f"  DEGRADED: the MCAP log failed: {_s(st['log_failure'])}")
        lines.extend(format_log(st))
        g = _dict(st.get("group"))
        if g:
            lines.append(
                f"  group {_s(g.get('name'), 80)}: members {', '.join(_strs(g.get('members')))}"
                f"{'' if g.get('joined') else ' (joining)'}; {plural(_num(g.get('takeovers')), 'unit')} "
                f"taken over, {_int(g.get('released'))} released, {_int(g.get('held_units'))} held"
            )
            for unit, u in sorted(_dict(g.get("unmonitored")).items()):
                lines.append(
                    f"  UNMONITORED {_s(unit, 260)}: no member's health output for more than "
                    f"{_fmt(g.get('unmonitored_s'), 'g')} s (owner: "
                    f"{_s(_dict(u).get('owner') or '-', 80)})"
                )
        fx = _dict(st.get("foxglove"))
        if fx:
            gd = _dict(fx.get("guard"))
            mem = (
                f", {_int(gd.get('connections'))}/{_int(gd.get('max_connections'))} viewers, "
                f"{_fmt((_num(gd.get('buffered_bytes')) or 0) / 2**20, '.1f')} of "
                f"{_fmt((_num(gd.get('memory_bound_bytes')) or 0) / 2**20, '.0f')} MiB buffered"
                if gd
                else ""
            )
            lines.append(
                f"  foxglove ws://{_s(fx.get('listen'), 80)}: {_int(fx.get('subscribed_topics'))} "
                f"topics subscribed, {_int(fx.get('sent'))} sent, {_int(fx.get('dropped'))} "
                f"dropped{mem}"
            )
        if st.get("feed_failure"):
            lines.append(f"  DEGRADED: {_s(st['feed_failure'])}")
        for _name, a in sorted(_dict(st.get("actuators")).items()):
            if isinstance(a, dict):
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
