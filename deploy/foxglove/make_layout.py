"""Write the Foxglove layout of one actuator (deploy/foxglove/servowatch-layout.json), made by
``service.edge.foxglove_layout`` (what ``servowatch layout --unit AC/ACT`` writes).

    .venv/bin/python deploy/foxglove/make_layout.py                      # AC001/elevator_L
    .venv/bin/python deploy/foxglove/make_layout.py --actuator AC007/aileron_R --out my.json

Panels (docs/dashboard.md, "Live in Foxglove"): C_Lk with its baseline and its alarm levels,
P_SR, the innovations (residuals) of the pressures and of the positions, NIS with its
two-sided 95 % chi-square band, the alarm states and the last alarm events. The topics and
fields are the MCAP log's (service.edge.foxglove_feed), so the layout opens a log and a live
daemon alike. Two user scripts derive what the messages do not carry: the baseline C_Lk
(C_Lk / leak_ratio) with the alarm levels (leak_raise, leak_clear of MonitorConfig), and the
NIS band of each row's degrees of freedom (scipy's chi2, tabulated here).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from service.edge.foxglove_layout import build  # noqa: E402  (the layout of any unit)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--actuator", default="AC001/elevator_L", metavar="AIRCRAFT/ACTUATOR")
    p.add_argument("--out", default=str(Path(__file__).with_name("servowatch-layout.json")))
    a = p.parse_args(argv)
    aircraft, _, actuator = a.actuator.partition("/")
    if not aircraft or not actuator:
        p.error("--actuator: expected AIRCRAFT/ACTUATOR")
    Path(a.out).write_text(json.dumps(build(aircraft, actuator), indent=2) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
