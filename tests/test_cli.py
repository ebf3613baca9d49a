"""The command dispatcher: every command exists, negative numbers as option values."""

from __future__ import annotations

import subprocess
import sys

import pytest

from service.cli.dispatch import COMMANDS, _join_negative_values, build_parser


def test_every_command_module_is_present():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(sub.choices) == set(COMMANDS)


def test_single_command_parser_matches_full_parser():
    args = build_parser("characteristic").parse_args(["characteristic", "--model", "C5"])
    assert args.model == "C5" and callable(args._run)


def test_negative_values_joined_to_their_option():
    assert _join_negative_values(["--x-s", "-1e-4,0", "--json"]) == ["--x-s=-1e-4,0", "--json"]
    assert _join_negative_values(["--q-j", ".5"]) == ["--q-j", ".5"]
    assert _join_negative_values(["--p-sr", "-.5"]) == ["--p-sr=-.5"]


@pytest.mark.parametrize("argv", [[], ["bogus"]])
def test_usage_errors_exit_2(argv):
    r = subprocess.run(
        [sys.executable, "-m", "service.cli", *argv], capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 2
    assert "usage" in r.stderr and r.stdout == ""


@pytest.mark.parametrize("cmd", [["status", "--timeout", "1"], ["inject", "--fault", "clear"]])
def test_unreachable_router_exits_3_naming_the_endpoint(cmd, capsys):
    from service.cli import main
    from service.zenoh_util import free_port

    ep = f"tcp/127.0.0.1:{free_port()}"  # nothing listens there
    assert main([*cmd, "--connect", ep, "--mode", "client"]) == 3
    err = capsys.readouterr().err
    assert "cannot open a Zenoh session" in err and ep in err


@pytest.mark.slow
def test_run_exits_4_when_the_log_fails(tmp_path):
    """``servowatch run`` with a log that cannot be written (/dev/full: ENOSPC) keeps
    monitoring, then exits with EXIT_LOG_FAILURE and the failure in its final status."""
    import json

    from service.daemon import EXIT_LOG_FAILURE
    from service.zenoh_util import free_port

    cfg = tmp_path / "svc.toml"
    cfg.write_text(f'[zenoh]\nmode = "peer"\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n')
    r = subprocess.run(
        [sys.executable, "-m", "service.cli", "run", "--config", str(cfg), "--log", "/dev/full",
         "--no-rotate", "--duration", "1", "--json"],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert r.returncode == EXIT_LOG_FAILURE == 5, r.stderr[-2000:]
    final = json.loads(r.stdout)
    assert final["state"] == "degraded" and "No space left" in final["log_failure"]
    assert "the MCAP log failed" in r.stderr
