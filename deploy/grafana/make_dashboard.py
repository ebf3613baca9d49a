"""Write the Grafana dashboard over the daemons' metrics (deploy/grafana/servowatch.json).

    .venv/bin/python deploy/grafana/make_dashboard.py [--out F.json]

Three rows (docs/dashboard.md, "Grafana"): the fleet overview (units, active alarms, silent
units, every unit's leak ratio, supply ratio and RUL), one unit's ratios (chosen with the
``aircraft`` and ``actuator`` variables: leak ratio with the alarm levels, supply ratio, NIS
in band, C_Lk with its 1-sigma, alarm states, RUL), and the daemons' health (sample rate,
dropped, bad and missing samples, queue, latency percentiles, log, store, group, Foxglove).
Every query names metrics of ``service.edge.metrics.METRICS`` (tests/test_grafana.py). The alarm
levels drawn are the defaults of ``[monitor.alarms]`` (``leak_raise``, ``leak_clear``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

DS = {"type": "prometheus", "uid": "${datasource}"}
ST = 'station=~"$station"'
UNIT = f'{ST},aircraft="$aircraft",actuator="$actuator"'
UNIT_LEGEND = "{{aircraft}}/{{actuator}}"


class _Ids:
    def __init__(self) -> None:
        self.n = 0

    def __call__(self) -> int:
        self.n += 1
        return self.n


def _target(expr: str, legend: str = "", ref: str = "A", instant: bool = False) -> dict:
    t = {"datasource": DS, "expr": expr, "legendFormat": legend, "refId": ref}
    if instant:
        t.update(instant=True, range=False, format="table")
    return t


def _panel(
    ids: _Ids, kind: str, title: str, queries: list[tuple[str, str]],
    grid: tuple[int, int, int, int], *, instant: bool = False, unit: str | None = None,
    thresholds: list[tuple[str, float | None]] | None = None, description: str = "",
    options: dict | None = None, decimals: int | None = None,
) -> dict:  # fmt: skip
    """One panel of ``kind`` at ``grid`` (x, y, w, h) drawing ``queries`` [(expression,
    legend)], refIds A, B, ... in order."""
    x, y, w, h = grid
    targets = [_target(e, lg, chr(ord("A") + j), instant) for j, (e, lg) in enumerate(queries)]
    defaults: dict = {}
    if unit:
        defaults["unit"] = unit
    if decimals is not None:
        defaults["decimals"] = decimals
    if thresholds:
        defaults["thresholds"] = {
            "mode": "absolute",
            "steps": [{"color": c, "value": v} for c, v in thresholds],
        }
        if kind == "timeseries":
            defaults["custom"] = {"thresholdsStyle": {"mode": "line"}}
    return {
        "id": ids(),
        "type": kind,
        "title": title,
        "description": description,
        "datasource": DS,
        "gridPos": {"x": x, "y": y, "w": w, "h": h},
        "targets": targets,
        "fieldConfig": {"defaults": defaults, "overrides": []},
        "options": options or {},
    }


def _row(ids: _Ids, title: str, y: int) -> dict:
    return {"id": ids(), "type": "row", "title": title, "collapsed": False,
            "gridPos": {"x": 0, "y": y, "w": 24, "h": 1}, "panels": []}  # fmt: skip


def _var(name: str, query: str, label: str, *, multi: bool = False) -> dict:
    return {
        "name": name, "label": label, "type": "query", "datasource": DS,
        "query": {"query": query, "refId": f"var_{name}"}, "definition": query,
        "refresh": 2, "sort": 1, "multi": multi, "includeAll": multi,
        **({"allValue": ".*"} if multi else {}),
        "current": {},
    }  # fmt: skip


def dashboard(leak_raise: float = 2.5, leak_clear: float = 2.0) -> dict:
    """The dashboard as a dict (Grafana's JSON model, schemaVersion 39)."""
    ids = _Ids()
    p: list[dict] = []
    ok_red = [("green", None), ("red", 1)]
    # -- fleet overview --------------------------------------------------------------------
    p.append(_row(ids, "Fleet overview", 0))
    stats = [
        ("Units monitored", f"sum(servowatch_units{{{ST}}})", None),
        ("Leak alarms", f'sum(servowatch_unit_alarm{{{ST},kind="leak"}})', ok_red),
        ("Supply alarms", f'sum(servowatch_unit_alarm{{{ST},kind="supply"}})', ok_red),
        ("Silent units", f"sum(servowatch_silent_units{{{ST}}})", [("green", None), ("orange", 1)]),
        ("Not commissioned", f"count(servowatch_unit_commissioned{{{ST}}} == 0) or vector(0)",
         [("green", None), ("orange", 1)]),
        ("Degraded daemons", f"sum(servowatch_degraded{{{ST}}})", ok_red),
    ]  # fmt: skip
    for i, (title, expr, th) in enumerate(stats):
        p.append(_panel(ids, "stat", title, [(expr, "")], (4 * i, 1, 4, 4), thresholds=th))
    leak_levels = [("green", None), ("orange", leak_clear), ("red", leak_raise)]
    bars = [
        ("Leak ratio (C_Lk / baseline), every unit",
         f"sort_desc(servowatch_unit_leak_ratio{{{ST}}})", {
            "decimals": 2, "thresholds": leak_levels,
            "description": "the last scraped leak ratio of each unit; orange from leak_clear, "
            "red from leak_raise ([monitor.alarms] defaults)",
        }),
        ("Supply ratio (P_SR / rated), every unit",
         f"sort(servowatch_unit_supply_ratio{{{ST}}})", {
            "decimals": 2, "thresholds": [("red", None), ("green", 0.8)],
        }),
        ("RUL median [flights], every unit that has one",
         f"sort(servowatch_unit_rul_median_flights{{{ST}}})", {
            "decimals": 0, "unit": "none",
            "thresholds": [("red", None), ("orange", 10), ("green", 50)],
            "description": "the RUL `servowatch rul` last stored, on units whose history "
            "counts flights (servowatch_unit_rul_median_hours for the others)",
        }),
    ]  # fmt: skip
    for i, (title, expr, kw) in enumerate(bars):
        p.append(_panel(
            ids, "bargauge", title, [(expr, UNIT_LEGEND)], (8 * i, 5, 8, 9),
            instant=True, **kw,
            options={"orientation": "horizontal", "displayMode": "basic",
                     "reduceOptions": {"calcs": ["lastNotNull"], "values": True}},
        ))  # fmt: skip
    p.append(_panel(
        ids, "timeseries", "Leak ratio, the 10 highest",
        [(f"topk(10, servowatch_unit_leak_ratio{{{ST}}})", UNIT_LEGEND)], (0, 14, 24, 8),
        decimals=2, thresholds=leak_levels,
    ))  # fmt: skip
    # -- one unit --------------------------------------------------------------------------
    p.append(_row(ids, "Unit $aircraft/$actuator", 22))
    one_unit = [
        ("timeseries", "Leak ratio (C_Lk / baseline)",
         [("servowatch_unit_leak_ratio", "leak ratio")], (0, 23, 12, 8), {
            "decimals": 2, "thresholds": leak_levels,
            "description": f"alarm raised at {leak_raise}, cleared at {leak_clear} "
            "([monitor.alarms] defaults)",
        }),
        ("timeseries", "Supply ratio (P_SR / rated)",
         [("servowatch_unit_supply_ratio", "supply ratio")], (12, 23, 12, 8), {"decimals": 3}),
        ("timeseries", "C_Lk and its 1-sigma [m^3/(s Pa)]",
         [("servowatch_unit_c_lk", "C_Lk"), ("servowatch_unit_c_lk_sigma", "1-sigma")],
         (0, 31, 8, 8), {"unit": "sci"}),
        ("timeseries", "NIS in band (open operating period)",
         [("servowatch_unit_nis_in_band_ratio", "in 95 % band")], (8, 31, 8, 8), {
            "unit": "percentunit", "thresholds": [("red", None), ("green", 0.8)],
            "description": "fraction of the outputs whose NIS lies in its two-sided 95 % "
            "chi-square band: about 0.95 for a filter that fits the unit",
        }),
        ("state-timeline", "Alarms", [("servowatch_unit_alarm", "{{kind}}")], (16, 31, 8, 4),
         {"thresholds": ok_red}),
        ("stat", "RUL median",
         [("servowatch_unit_rul_median_flights", "flights"),
          ("servowatch_unit_rul_median_days", "days"),
          ("servowatch_unit_rul_median_hours", "operating hours")],
         (16, 35, 8, 4), {"decimals": 0}),
    ]  # fmt: skip
    for kind, title, qs, grid, kw in one_unit:
        queries = [(f"{name}{{{UNIT}}}", lg) for name, lg in qs]
        p.append(_panel(ids, kind, title, queries, grid, **kw))
    # -- daemon health ---------------------------------------------------------------------
    d = "{{station}}/{{shard}}"
    p.append(_row(ids, "Daemon health", 39))
    health = [
        ("Samples per second", [(f"rate(servowatch_samples_total{{{ST}}}[$__rate_interval])", d)],
         "none"),
        ("Dropped, bad, gaps, missed per second", [
            (f"rate(servowatch_dropped_total{{{ST}}}[$__rate_interval])", d + " dropped"),
            (f"rate(servowatch_bad_total{{{ST}}}[$__rate_interval])", d + " bad"),
            (f"rate(servowatch_gaps_total{{{ST}}}[$__rate_interval])", d + " gaps"),
            (f"rate(servowatch_missed_total{{{ST}}}[$__rate_interval])", d + " missed"),
        ], "none"),
        ("Latency (receipt to health output)", [
            ("histogram_quantile(0.5, sum by (le, station, shard) "
             f"(rate(servowatch_latency_seconds_bucket{{{ST}}}[$__rate_interval])))", d + " p50"),
            ("histogram_quantile(0.99, sum by (le, station, shard) "
             f"(rate(servowatch_latency_seconds_bucket{{{ST}}}[$__rate_interval])))", d + " p99"),
        ], "s"),
        ("Receive queue", [
            (f"servowatch_queue_messages{{{ST}}}", d + " queued"),
            (f"servowatch_queue_high_messages{{{ST}}}", d + " high-water"),
            (f"servowatch_queue_capacity_messages{{{ST}}}", d + " capacity"),
        ], "none"),
        ("Worker busy", [(f"servowatch_busy_ratio{{{ST}}}", d)], "percentunit"),
        ("MCAP log", [
            (f"servowatch_log_bytes{{{ST}}}", d + " bytes"),
        ], "bytes"),
        ("Failures", [
            (f"servowatch_log_failed{{{ST}}}", d + " log failed"),
            (f"servowatch_store_failed{{{ST}}}", d + " store failed"),
            (f"increase(servowatch_store_errors_total{{{ST}}}[1h])", d + " store errors/h"),
            (f"increase(servowatch_errors_total{{{ST}}}[1h])", d + " errors/h"),
        ], "none"),
        ("Health store", [
            (f"servowatch_store_pending{{{ST}}}", d + " pending"),
            (f"increase(servowatch_store_written_total{{{ST}}}[1h])", d + " periods/h"),
        ], "none"),
        ("Monitor group", [
            (f"servowatch_group_members{{{ST}}}", d + " members"),
            (f"increase(servowatch_group_takeovers_total{{{ST}}}[1h])", d + " takeovers/h"),
            (f"increase(servowatch_group_released_total{{{ST}}}[1h])", d + " released/h"),
            (f"servowatch_group_held_units{{{ST}}}", d + " held"),
            (f"servowatch_group_unmonitored_units{{{ST}}}", d + " unmonitored"),
        ], "none"),
        ("Foxglove", [
            (f"servowatch_foxglove_subscribed_channels{{{ST}}}", d + " subscribed channels"),
            (f"rate(servowatch_foxglove_sent_total{{{ST}}}[$__rate_interval])", d + " sent/s"),
            (f"rate(servowatch_foxglove_dropped_total{{{ST}}}[$__rate_interval])",
             d + " dropped/s"),
        ], "none"),
        ("Uptime", [(f"servowatch_uptime_seconds{{{ST}}}", d)], "s"),
        ("Model and state", [(f"servowatch_info{{{ST}}}", d + " {{model}} {{state}}")], "none"),
    ]  # fmt: skip
    for i, (title, qs, u) in enumerate(health):
        grid = (8 * (i % 3), 40 + 7 * (i // 3), 8, 7)
        p.append(_panel(ids, "timeseries", title, qs, grid, unit=u))
    return {
        "title": "servowatch",
        "uid": "servowatch-fleet",
        "description": 'servowatch daemons\' metrics (docs/dashboard.md, "Grafana")',
        "tags": ["servowatch"],
        "timezone": "utc",
        "schemaVersion": 39,
        "version": 1,
        "editable": True,
        "refresh": "10s",
        "time": {"from": "now-1h", "to": "now"},
        "templating": {
            "list": [
                {
                    "name": "datasource",
                    "label": "Prometheus",
                    "type": "datasource",
                    "query": "prometheus",
                    "current": {},
                },
                _var("station", "label_values(servowatch_info, station)", "station", multi=True),
                _var(
                    "aircraft",
                    f"label_values(servowatch_unit_leak_ratio{{{ST}}}, aircraft)",
                    "aircraft",
                ),
                _var(
                    "actuator",
                    f'label_values(servowatch_unit_leak_ratio{{{ST},aircraft="$aircraft"}}, '
                    "actuator)",
                    "actuator",
                ),
            ]
        },  # fmt: skip
        "annotations": {"list": []},
        "panels": p,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).with_name("servowatch.json")))
    args = ap.parse_args(argv)
    from service.monitor import MonitorConfig

    al = MonitorConfig().alarms
    text = json.dumps(dashboard(al.leak_raise, al.leak_clear), indent=2) + "\n"
    Path(args.out).write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
