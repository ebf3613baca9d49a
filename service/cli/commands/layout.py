"""``servowatch layout``: the Foxglove layout of any unit (docs/dashboard.md, "Live in
Foxglove")."""

from __future__ import annotations

import argparse
import re
import sys

from service.cli.util import check_outputs, fail

NAME = "layout"
HELP = "write the Foxglove layout (C_Lk, alarms, residuals, NIS, events) of one unit AC/ACT"

_PART = re.compile(r"^[A-Za-z0-9_.\-]+$")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--unit", required=True, metavar="AIRCRAFT/ACTUATOR",
                   help="the unit whose topics the panels show, e.g. AC002/aileron_R")  # fmt: skip
    p.add_argument("--out", default=None, metavar="F.json",
                   help="the layout file (default: servowatch-layout-AIRCRAFT-ACTUATOR.json; "
                   "'-': stdout)")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    aircraft, _, actuator = args.unit.partition("/")
    if not (_PART.match(aircraft) and _PART.match(actuator)):
        return fail(
            f"--unit: expected AIRCRAFT/ACTUATOR (letters, digits, _ . -), got {args.unit!r}"
        )
    from service.edge.foxglove_layout import layout_json

    text = layout_json(aircraft, actuator)
    if args.out == "-":
        sys.stdout.write(text)
        return 0
    out = args.out or f"servowatch-layout-{aircraft}-{actuator}.json"
    check_outputs([("--out", out)], [])
    with open(out, "w", encoding="utf-8") as f:
        f.write(text)
    print(f"servowatch: wrote {out} (open it in Foxglove: Layouts, Import from file)",
          file=sys.stderr)  # fmt: skip
    return 0
