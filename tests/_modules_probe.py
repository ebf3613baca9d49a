"""``servowatch ARGS...`` in this process, then, at exit, the sorted names of the loaded
modules as one JSON line on stderr after ``MODULES ``. For the start-up import tests.

    python tests/_modules_probe.py router --listen tcp/127.0.0.1:P
"""

from __future__ import annotations

import atexit
import json
import sys


def _report() -> None:
    sys.stderr.write("MODULES " + json.dumps(sorted(sys.modules)) + "\n")
    sys.stderr.flush()


if __name__ == "__main__":
    atexit.register(_report)
    from service.cli import main

    sys.exit(main(sys.argv[1:]))
