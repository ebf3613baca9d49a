"""``servowatch --help`` and ``servowatch CMD --help`` for every command, as a user types
them (the venv's console script in a subprocess): each exits 0 and prints its usage."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from evaluation.restart import servowatch_exe
from service.cli.dispatch import COMMANDS, _load, help_of


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*servowatch_exe(), *args],
        capture_output=True, text=True, timeout=120, env={**os.environ, "COLUMNS": "200"},
    )  # fmt: skip


def test_top_level_help_lists_every_command():
    r = _run("--help")
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("usage: servowatch") and r.stderr == ""
    for name in COMMANDS:
        assert re.search(rf"\n    {name}\s", r.stdout), name
    assert "90 % interval" in r.stdout  # the rul help, its '%' printed as written


@pytest.mark.parametrize("name", COMMANDS)
def test_command_help_exits_0(name):
    r = _run(name, "--help")
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"usage: servowatch {name}"), r.stdout[:200]
    assert "options:" in r.stdout and r.stderr == ""


@pytest.mark.parametrize("name", COMMANDS)
def test_help_read_from_the_source_is_the_modules(name):
    assert help_of(name) == _load(name).HELP


def test_console_script_is_the_venvs():
    assert servowatch_exe()[0] != sys.executable  # the test runs the real console script
