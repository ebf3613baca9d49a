"""Resume time and samples lost across a router restart (kill -9 of `servowatch router`, the
same command back on the same port).

    .venv/bin/python bench/restart.py [--link actuator|daemon] [--down 1.0] [--rate 250] [--runs 3]

Every piece runs in its own process on loopback (evaluation.restart); prints one JSON
line per run: ``listen_s`` from the restarted router's spawn to its port accepting,
``resume_s`` from it listening to the daemon holding a sample published after that,
``flowing_s`` from its spawn to that sample (the chain flowing again), ``lost`` sequence
numbers never logged, ``missed`` messages Zenoh reported unrecoverable.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from evaluation.restart import run_restart  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--link", choices=("actuator", "daemon", "both"), default="both")
    p.add_argument("--down", type=float, default=1.0, help="router down for this long [s]")
    p.add_argument("--rate", type=float, default=250.0, help="actuator sample rate [Hz]")
    p.add_argument("--runs", type=int, default=1)
    a = p.parse_args()
    links = ("actuator", "daemon") if a.link == "both" else (a.link,)
    for link in links:
        for _ in range(a.runs):
            with tempfile.TemporaryDirectory() as tmp:
                r = run_restart(Path(tmp), link=link, down_s=a.down, rate_hz=a.rate)
            print(json.dumps({k: r[k] for k in r if k != "lost_seq"}), flush=True)


if __name__ == "__main__":
    main()
