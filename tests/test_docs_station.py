"""What a new user reads on a fresh clone (issue 54, "Docs"): no path of a maintainer's
checkout, no paragraph said twice, the README says how long ``make test`` takes."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: an absolute path into someone's home or work tree (not /etc, /var, /run, /opt, /tmp)
CHECKOUT = re.compile(r"(?<![\w.~-])/(?:work|home|Users|root)/[\w.-]+")


#: what a clone holds that is not the project's text (run outputs, the venv, caches)
_NOT_TEXT = {"tests", "logs", "servowatch-data", "build", "dist", "__pycache__"}


def _texts() -> list[Path]:
    """The README and every text file of the clone's folders (docs, deploy, the packages,
    the scripts), but the tests (which name such paths to test the check)."""
    files = [ROOT / "README.md"]
    for d in sorted(ROOT.iterdir()):
        if d.is_dir() and not d.name.startswith(".") and d.name not in _NOT_TEXT:
            files += [p for p in sorted(d.rglob("*")) if not (_NOT_TEXT & set(p.parts))]
    return [p for p in files if p.is_file() and p.suffix in _SUFFIXES]


_SUFFIXES = {".md", ".py", ".toml", ".service", ".socket", ".yml", ".yaml", ".json", ".txt",
             ".cfg", ".conf", ".sh", ".env", ""}  # fmt: skip


def find_checkout_paths(text: str) -> list[str]:
    return CHECKOUT.findall(text)


def test_the_check_finds_the_path_issue_54_met():
    assert find_checkout_paths("`bench/worker.py --compare-tree /work/main`") == ["/work/main"]
    assert find_checkout_paths("/home/ann/servowatch and ~/x") == ["/home/ann"]
    assert find_checkout_paths("/etc/servowatch /var/lib/servowatch /opt/x ./work/a") == []


def test_no_doc_names_a_path_of_a_maintainers_checkout():
    bad = [f"{p.relative_to(ROOT)}: {m}" for p in _texts()
           for m in find_checkout_paths(p.read_text(errors="replace"))]  # fmt: skip
    assert bad == []


def test_no_paragraph_is_said_twice():
    for p in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        paras = [x.strip() for x in re.split(r"\n\s*\n", p.read_text()) if len(x.strip()) > 80]
        twice = [k[:80] for k, n in Counter(paras).items() if n > 1]
        assert twice == [], p.name


def test_the_readme_says_how_long_make_test_takes():
    text = " ".join((ROOT / "README.md").read_text().split())
    assert re.search(r"`make test` takes about \d+-\d+ minutes", text), "README: make test"


def test_the_grafana_import_is_the_one_the_docs_describe():
    """docs/dashboard.md: the file asks for nothing at import (no ``__inputs``); a
    ``datasource`` variable labelled *Prometheus* that every panel and query uses."""
    import json

    dash = json.loads((ROOT / "deploy" / "grafana" / "servowatch.json").read_text())
    doc = " ".join((ROOT / "docs" / "dashboard.md").read_text().split())
    assert "it has no `__inputs`" in doc and "*Prometheus* variable" in doc
    assert "__inputs" not in dash and "__requires" not in dash
    (var,) = [v for v in dash["templating"]["list"] if v["type"] == "datasource"]
    assert var["label"] == "Prometheus" and var["query"] == "prometheus"
    uid = "${" + var["name"] + "}"
    panels = [p for p in dash["panels"] if p["type"] != "row"]
    assert panels and all(p["datasource"]["uid"] == uid for p in panels)
    assert all(t["datasource"]["uid"] == uid for p in panels for t in p.get("targets", []))
