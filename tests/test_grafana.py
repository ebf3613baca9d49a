"""The Grafana dashboard (deploy/grafana/servowatch.json): every query names metrics the
daemon's endpoint serves, the file is what its generator writes, and it has the fleet
overview, one unit's ratios and the daemons' health."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

from service.edge.metrics import collect_status
from tests.test_metrics import full_status

ROOT = Path(__file__).resolve().parents[1]
DASH = ROOT / "deploy" / "grafana" / "servowatch.json"
NAME = re.compile(r"\bservowatch_[a-z0-9_]+")


def _exprs(dash: dict) -> list[str]:
    """Every PromQL expression of the dashboard: panel targets and variable queries."""
    out = []

    def walk(panels: list[dict]) -> None:
        for p in panels:
            out.extend(t["expr"] for t in p.get("targets", ()) if "expr" in t)
            walk(p.get("panels", ()))

    walk(dash["panels"])
    for v in dash["templating"]["list"]:
        q = v.get("query")
        if isinstance(q, dict):
            out.append(q["query"])
    return out


def served_names() -> set[str]:
    """The sample names of a scrape of a daemon with every part (a group, a live feed, a
    store, a unit with a RUL)."""
    return {s.name for f in collect_status(full_status()) for s in f.samples}


def unknown_metrics(dash: dict) -> list[tuple[str, str]]:
    """(expression, name) of every metric named in ``dash`` that the endpoint does not serve,
    and of every expression that names none."""
    served = served_names()
    bad = []
    for e in _exprs(dash):
        names = NAME.findall(e)
        if not names:
            bad.append((e, "(no servowatch metric)"))
        bad.extend((e, n) for n in names if n not in served)
    return bad


def test_every_query_names_a_served_metric():
    dash = json.loads(DASH.read_text())
    exprs = _exprs(dash)
    assert len(exprs) > 30
    assert unknown_metrics(dash) == []
    # the check itself: a renamed or misspelt metric is caught
    broken = json.loads(DASH.read_text())
    broken["panels"][1]["targets"][0]["expr"] = "sum(servowatch_unit_leak_ration)"
    assert unknown_metrics(broken) == [
        ("sum(servowatch_unit_leak_ration)", "servowatch_unit_leak_ration")
    ]


def test_rows_and_unit_variables():
    dash = json.loads(DASH.read_text())
    rows = [p["title"] for p in dash["panels"] if p["type"] == "row"]
    assert rows == ["Fleet overview", "Unit $aircraft/$actuator", "Daemon health"]
    names = [v["name"] for v in dash["templating"]["list"]]
    assert names == ["datasource", "station", "aircraft", "actuator"]
    # the unit row's panels all select the chosen unit
    i0 = next(i for i, p in enumerate(dash["panels"]) if p["title"].startswith("Unit $"))
    i1 = next(i for i, p in enumerate(dash["panels"]) if p["title"] == "Daemon health")
    for p in dash["panels"][i0 + 1 : i1]:
        for t in p["targets"]:
            assert 'aircraft="$aircraft",actuator="$actuator"' in t["expr"], t["expr"]
    unit_families = {n for e in _exprs(dash) for n in NAME.findall(e) if "_unit_" in n}
    for want in ("leak_ratio", "supply_ratio", "nis_in_band_ratio", "alarm", "rul_median_flights"):
        assert f"servowatch_unit_{want}" in unit_families


def test_file_is_the_generators_output(tmp_path):
    spec = importlib.util.spec_from_file_location(
        "make_dashboard", ROOT / "deploy" / "grafana" / "make_dashboard.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "d.json"
    assert mod.main(["--out", str(out)]) == 0
    assert out.read_text() == DASH.read_text()
