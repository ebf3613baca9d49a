"""What `pip install .` (the container image) carries: every package directory and the fleet
page's static files, read from pyproject.toml the way setuptools reads it."""

from __future__ import annotations

import fnmatch
import tomllib
from pathlib import Path

from setuptools import find_packages

ROOT = Path(__file__).resolve().parents[1]


def _setuptools() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_every_package_directory_is_installed():
    found = set(find_packages(str(ROOT), include=_setuptools()["packages"]["find"]["include"]))
    on_disk = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for top in ("models", "service", "evaluation")
        for p in (ROOT / top).rglob("__init__.py")
    }
    assert "service.edge.web" in on_disk and "service.store" in on_disk and "evaluation" in on_disk
    assert on_disk <= found, sorted(on_disk - found)
    # benchmarks, one-off investigations and tests are scripts, not packages
    assert not any(p.split(".")[0] in ("tests", "bench", "research") for p in found)


def test_the_page_files_are_package_data():
    globs = _setuptools()["package-data"]["service.edge.web"]
    static = ROOT / "service" / "edge" / "web" / "static"
    files = [p.relative_to(static.parent).as_posix() for p in static.iterdir() if p.is_file()]
    assert {"static/index.html", "static/fleet.js", "static/fleet.css"} <= set(files)
    for f in files:
        assert any(fnmatch.fnmatch(f, g) for g in globs), f
