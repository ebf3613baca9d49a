"""The ``servowatch`` command line: one module per subcommand under ``service.cli.commands``.

Each command module exposes ``NAME``, ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. SI units in and out; ``--json`` prints exactly one JSON object on stdout.
Bad arguments exit 2 (argparse), a bad input file exits 2 with a message naming it; the exit
codes are ``service.cli.util.EXIT_*`` (docs/cli.md, "Exit codes"). Whatever a user can cause
ends in one line on stderr, never a traceback: a command raises ``CommandError`` (its message
and code), and ``main`` turns a ``StoreError`` (exit 2), an ``OSError`` or a store engine's
error met during the work (exit 5) into one line as a backstop. Every command logs in the
one format of ``service.log.setup`` (its warnings as plain text lines; the services' JSON).
"""

from __future__ import annotations

import argparse
import ast
import importlib
import importlib.util
import re
import sys
from collections.abc import Sequence

__all__ = ["main", "COMMANDS", "build_parser"]

COMMANDS: tuple[str, ...] = (
    "characteristic",
    "simulate",
    "compare",
    "estimate",
    "calibrate",
    "baselines",
    "fleet",
    "web",
    "rul",
    "fleet-sim",
    "actuator",
    "inject",
    "run",
    "status",
    "listen",
    "router",
    "replay",
    "demo",
    "warmup",
    "import",
    "layout",
)


def _module_name(name: str) -> str:
    return f"service.cli.commands.{name.replace('-', '_')}" + ("_" if name == "import" else "")


def _load(name: str):
    return importlib.import_module(_module_name(name))


def help_of(name: str) -> str:
    """The ``HELP`` string of a command module, read from its source without importing it
    (the top-level ``--help`` lists every command without paying for their imports)."""
    spec = importlib.util.find_spec(_module_name(name))
    if spec is None or spec.origin is None:
        raise ImportError(f"no command module for {name!r}")
    with open(spec.origin, encoding="utf-8") as f:
        tree = ast.parse(f.read(), spec.origin)
    for node in tree.body:
        if (
            isinstance(node, ast.Assign)
            and any(isinstance(t, ast.Name) and t.id == "HELP" for t in node.targets)
            and isinstance(node.value, ast.Constant)
            and isinstance(node.value.value, str)
        ):
            return node.value.value
    return _load(name).HELP  # not a plain string literal: import it


def build_parser(only: str | None = None, *, summary: bool = False) -> argparse.ArgumentParser:
    """The top-level parser with every subcommand, or just ``only`` (a command module is
    imported only when needed, which keeps start-up fast). ``summary``: every subcommand with
    its one-line help and no arguments, no command module imported (for ``servowatch --help``
    and usage errors)."""
    parser = argparse.ArgumentParser(
        prog="servowatch",
        description="Prognostics and health monitoring for electro-hydraulic actuators.",
        epilog="`servowatch COMMAND --help` describes a command's options (docs/cli.md).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS if only is None else (only,):
        if summary:
            sub.add_parser(name, help=_escape(help_of(name)))
            continue
        mod = _load(name)
        p = sub.add_parser(name, help=_escape(mod.HELP), description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def version() -> str:
    """The installed servowatch's version (its package metadata), or ``unknown`` for a
    source tree that is not installed."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as _v

    try:
        return _v("servowatch")
    except PackageNotFoundError:
        return "unknown"


def _escape(text: str) -> str:
    """argparse %-formats help strings: a literal ``%`` (``90 % interval``) must be ``%%``."""
    return text.replace("%", "%%")


_NEG_NUMBER = re.compile(r"^-[\d.]")


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--x-s -1e-4,0`` -> ``--x-s=-1e-4,0``: argparse would take the value for an option."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        if (
            a.startswith("--")
            and "=" not in a
            and i + 1 < len(argv)
            and _NEG_NUMBER.match(argv[i + 1])
        ):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``servowatch`` console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    only = argv[0] if argv and argv[0] in COMMANDS else None
    parser = build_parser(only, summary=only is None)
    args = parser.parse_args(_join_negative_values(argv))
    from service.log.setup import setup_command_logging

    setup_command_logging()  # the services (run, actuator, router, web) set their own
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as e:
        code = _one_line(e, args)
        if code is None:
            raise
        return code


_STORE_ENGINES = ("sqlite3", "psycopg")


def _one_line(e: Exception, args: argparse.Namespace) -> int | None:
    """Report a failure a user can cause as one line on stderr and return its exit code;
    None for anything else (a bug: its traceback is kept)."""
    from service.cli.util import EXIT_IO, EXIT_USAGE, CommandError, _cause, fail

    if isinstance(e, CommandError):
        return fail(str(e), e.code)
    from service.store import StoreError

    if isinstance(e, StoreError):
        return fail(str(e), EXIT_USAGE)
    if isinstance(e, OSError):
        where = f"{e.filename}: " if e.filename else ""
        return fail(f"{where}{_cause(e)} (the command stopped here; outputs written so far "
                    "may be incomplete)", EXIT_IO)  # fmt: skip
    if type(e).__module__.split(".")[0] in _STORE_ENGINES:
        from service.store import default_store, describe_url

        target = getattr(args, "store", None) or default_store()
        text = str(e).lower()
        if "lock" in text:  # a reader's lock wait (READ_TIMEOUT_S) or a writer's ran out
            return fail(f"--store {describe_url(str(target))} is busy: a writer held its lock "
                        f"longer than this command waits ({_cause(e)}); nothing was written, "
                        "try again", EXIT_USAGE)  # fmt: skip
        what = "is damaged" if "malformed" in text or "not a database" in text else "failed"
        return fail(f"--store {describe_url(str(target))} {what}: {_cause(e)} (the command "
                    "stopped here; each store write is one transaction: what was committed "
                    "before stays, nothing is half-written)", EXIT_IO)  # fmt: skip
    return None


if __name__ == "__main__":
    sys.exit(main())
