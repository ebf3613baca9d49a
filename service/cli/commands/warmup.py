"""``servowatch warmup``: compile the numba kernels once, ahead of the first run.

A fresh install (``pip install``) has no compiled kernels: the first command that needs them
compiles them (and says so on stderr). ``make`` runs this after installing; a pip user runs
it once. Safe to repeat: compiled kernels load from numba's cache in seconds.
"""

from __future__ import annotations

import argparse
import sys

from service.cli.util import emit_json

NAME = "warmup"
HELP = "compile the numba kernels once (a first run: about a minute on 2 cores; then seconds)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from service.cli.warmup import DEFAULT_GROUPS, GROUPS

    p.add_argument(
        "--group", action="append", choices=tuple(GROUPS), default=None,
        help=f"only the kernels of this group (repeatable; default: {', '.join(DEFAULT_GROUPS)}; "
        "valves: the bench on the simplified valve models (simulate, compare); trend: the RUL's "
        "opt-in trend model (rul --robust-trend); each compiled on its first use otherwise)",
    )  # fmt: skip
    p.add_argument("--all", action="store_true", help="every group, valves and trend too")
    p.add_argument("--table", action="store_true", help="print the compile seconds of every kernel")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--jobs", type=int, default=None,
        help="processes of a cold compile (default: one per core, at most 4)",
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from service.cli.warmup import DEFAULT_GROUPS, GROUPS, ensure, print_table, table

    groups = tuple(GROUPS) if args.all else tuple(args.group or DEFAULT_GROUPS)
    if args.table:
        rows, wall = table(groups, args.jobs)
        if args.json:
            emit_json({"wall_s": wall, "kernels": [
                {"group": g, "kernel": k, "signatures": n, "own_s": o, "total_s": t}
                for g, k, n, o, t in rows
            ]})  # fmt: skip
        else:
            print_table(rows, wall)
        return 0
    from service.daemon.systemd import extending_start

    # as a unit's ExecStartPre (NotifyAccess=exec): systemd's start timeout is extended
    # while it compiles (deploy/servowatch.service)
    with extending_start("warmup: compiling the kernels (a first run takes minutes)"):
        wall = ensure(*groups, always=True, jobs=args.jobs)
    if args.json:
        emit_json({"groups": list(groups), "wall_s": wall})
    else:
        print(f"servowatch: compiled kernels ready ({wall:.1f} s)", file=sys.stderr)
    return 0
