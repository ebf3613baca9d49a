"""``servowatch listen``: print the est, res and health outputs the daemons publish."""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from collections import OrderedDict
from typing import Any

from service.cli.util import emit_json, fail, plural

NAME = "listen"
HELP = (
    "Print the outputs (est, res, health) the monitoring daemons publish on Zenoh: the "
    "protobuf rows, and the JSON of older daemons; malformed ones are counted."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from service.cli.args import add_zenoh_arguments

    p.add_argument(
        "--unit", default="*/*", help="AIRCRAFT/ACTUATOR to listen to (Zenoh wildcards: */*)"
    )
    p.add_argument(
        "--leaf", action="append", choices=("est", "res", "health"),
        help="output to listen to (repeatable; default: all three)",
    )  # fmt: skip
    p.add_argument("--count", type=int, default=0, help="stop after N outputs (0: no limit)")
    p.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: none)")
    p.add_argument(
        "--json", action="store_true",
        help="print one JSON object at the end (counts and each key's last output) instead "
        "of a line per output",
    )  # fmt: skip
    p.add_argument(
        "--write-schema", metavar="FILE",
        help="write the outputs' FileDescriptorSet (protobuf schema) to FILE and exit",
    )  # fmt: skip
    add_zenoh_arguments(p)


#: keys whose last output ``listen`` remembers at most (the least recently seen go first)
MAX_KEYS = 4096


def output_line(key: str, d: dict[str, Any]) -> str:
    """One output as a line: its sample time in RFC 3339 (``t``, a Unix time; a simulated
    time stays in seconds), the key, then the fields as JSON."""
    from service.log.retention import readable_time

    return f"{readable_time(d.get('t')).replace(' ', '')} {key} {json.dumps(d)}"


class OutputListener:
    """Decodes published outputs (``service.wire.messages.decode_output``), counting them per
    key and the malformed ones (a bad message is counted and logged on stderr, never an
    exception in Zenoh's thread); ``echo`` prints a line ``TIME KEY {json}`` per output
    (:func:`output_line`), ``count`` of them at most. The last output of at most
    ``max_keys`` keys is kept (least recently seen evicted, counted in ``evicted``): a
    publisher of many keys cannot grow it without bound."""

    def __init__(
        self, echo: bool = True, count: int = 0, out: Any = None, max_keys: int = MAX_KEYS
    ) -> None:
        self.echo, self.count = echo, count
        self.out = out if out is not None else sys.stdout
        self.received = 0
        self.malformed = 0
        self.evicted = 0
        self.max_keys = max(1, int(max_keys))
        self.last: OrderedDict[str, dict[str, Any]] = OrderedDict()
        self.done = threading.Event()
        self._lock = threading.Lock()

    def on_sample(self, key: str, payload: bytes, encoding: str | None) -> None:
        from service.wire.messages import (
            OUTPUT_LEAVES,
            MessageError,
            decode_output,
            parse_fleet_key,
        )

        try:
            leaf = parse_fleet_key(key)[2]
            if leaf not in OUTPUT_LEAVES:
                raise MessageError(f"not one of {OUTPUT_LEAVES}", "leaf")
            d = decode_output(leaf, payload, encoding)
        except Exception as e:  # MessageError; anything else is a bad message too
            with self._lock:
                self.malformed += 1
                n = self.malformed
            if n <= 10 or math.log10(n).is_integer():
                from service.log.escape import escape_controls

                print(f"listen: malformed output on {escape_controls(key, 200)} ({n} so far): "
                      f"{escape_controls(e, 300)}", file=sys.stderr)  # fmt: skip
            return
        with self._lock:
            if self.count and self.received >= self.count:
                return  # --count N: exactly N, whatever arrives before the subscribers go
            self.received += 1
            self.last[key] = d
            self.last.move_to_end(key)
            while len(self.last) > self.max_keys:
                self.last.popitem(last=False)
                self.evicted += 1
            if self.echo:
                print(output_line(key, d), file=self.out, flush=True)
            if self.count and self.received >= self.count:
                self.done.set()

    def summary(self) -> dict[str, Any]:
        with self._lock:
            return {"received": self.received, "malformed": self.malformed,
                    "evicted": self.evicted, "outputs": dict(sorted(self.last.items()))}  # fmt: skip


def summary_text(sm: dict[str, Any]) -> str:
    """The closing line: ``listen: 1 output, 0 malformed``."""
    return f"listen: {plural(sm['received'], 'output')}, {sm['malformed']} malformed"


def run(args: argparse.Namespace) -> int:
    from service.cli.args import open_zenoh_session, zenoh_config
    from service.wire.messages import output_schema

    if args.write_schema:
        try:
            with open(args.write_schema, "wb") as f:
                f.write(output_schema())
        except OSError as e:
            return fail(f"--write-schema {args.write_schema}: {e.strerror or e}", 5)
        return 0
    if args.count < 0 or not (args.duration >= 0 and math.isfinite(args.duration)):
        return fail("--count and --duration must be >= 0")
    unit = args.unit.strip("/")
    if unit.count("/") != 1:
        return fail(f"--unit: expected AIRCRAFT/ACTUATOR, got {args.unit!r}")
    session = open_zenoh_session(zenoh_config(args))
    lis = OutputListener(echo=not args.json, count=args.count)

    def cb(s) -> None:
        lis.on_sample(str(s.key_expr), s.payload.to_bytes(), str(s.encoding))

    leaves = args.leaf or ["est", "res", "health"]
    with session:
        subs = [session.declare_subscriber(f"fleet/{unit}/{leaf}", cb) for leaf in leaves]
        t_end = time.monotonic() + args.duration if args.duration else math.inf
        try:
            while not lis.done.wait(min(0.2, max(0.0, t_end - time.monotonic()))):
                if time.monotonic() >= t_end:
                    break
        except KeyboardInterrupt:
            pass
        for sub in subs:
            sub.undeclare()
    sm = lis.summary()
    if args.json:
        emit_json(sm)
    else:
        print(summary_text(sm), file=sys.stderr)
    return 0
