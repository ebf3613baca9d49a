"""Small helpers shared by the command modules: number-list parsing, JSON output, errors,
the exit codes and the checks of output paths (never an input, writable before the work)."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import Any

from service.jsonutil import jsonable as to_jsonable

__all__ = [
    "float_list", "finite_float", "emit_json", "fail", "to_jsonable", "CommandError",
    "EXIT_OK", "EXIT_REFUSED", "EXIT_USAGE", "EXIT_IO", "same_file", "refuse_output_is_input",
    "check_writable", "check_outputs", "writing", "plural",
]  # fmt: skip


def finite_float(text: str) -> float:
    """argparse type: a finite float (SI)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"not finite: {text!r}")
    return v


def float_list(text: str) -> list[float]:
    """argparse type: comma-separated finite floats, e.g. ``-1e-4,0,1e-4``."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts:
        raise argparse.ArgumentTypeError("expected a comma-separated list of numbers")
    return [finite_float(p) for p in parts]


def plural(n: Any, one: str, many: str | None = None) -> str:
    """``1 period``, ``3 periods``, ``- periods`` (``many``: the plural when not ``one + s``;
    ``n`` a finite count, anything else, e.g. a status field that is null, shown as ``-``)."""
    ok = not isinstance(n, bool) and isinstance(n, int | float) and math.isfinite(n)
    word = one if ok and n == 1 else (many or one + "s")
    shown = "-" if not ok else f"{n:.0f}" if float(n).is_integer() else f"{n:g}"
    return f"{shown} {word}"


def emit_json(obj: Any) -> None:
    """Print exactly one JSON object on stdout."""
    sys.stdout.write(json.dumps(to_jsonable(obj)) + "\n")
    sys.stdout.flush()


def fail(message: str, code: int = 2) -> int:
    """Print an error on stderr and return the exit code."""
    print(f"servowatch: error: {message}", file=sys.stderr)
    return code


# ----------------------------------------------------------------------- exit codes, errors

#: exit codes of every command (docs/cli.md, "Exit codes")
EXIT_OK = 0
EXIT_REFUSED = 1  # refused by the target (a daemon, the actuator), or the run found nothing
EXIT_USAGE = 2  # bad arguments, settings or input files; an output that is an input
EXIT_IO = 5  # a file or the store failed while being read or written (disk full, I/O error)
EXIT_INTERRUPTED = 130  # Ctrl-C

#: the table of every exit code (docs/cli.md, "Exit codes", checked by tests/test_docs_exit_codes.py):
#: 3 and 4 are the Zenoh session's (``service.config.EXIT_UNREACHABLE``, ``EXIT_REFUSED``),
#: 5 also the daemon's failed MCAP log (``service.daemon.EXIT_LOG_FAILURE``)
EXIT_CODES: dict[int, str] = {
    EXIT_OK: "ok",
    EXIT_REFUSED: "refused by the target, nothing came back, or part of a batch failed",
    EXIT_USAGE: "bad arguments, settings or input files, found before the work",
    3: "router or target not reachable",
    4: "connection refused at the TLS handshake",
    EXIT_IO: "a file or the store failed while being written or read, after the work started",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C)",
}


class CommandError(Exception):
    """A failure a user can cause, reported by ``service.cli.dispatch`` as one line on stderr
    (``servowatch: error: MESSAGE``) and the exit ``code``; never a traceback."""

    def __init__(self, message: str, code: int = EXIT_USAGE) -> None:
        super().__init__(message)
        self.code = int(code)


def _cause(e: BaseException) -> str:
    """The one-line cause of an exception (``strerror`` of an OSError)."""
    if isinstance(e, OSError) and e.strerror:
        return e.strerror
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


PathArg = str | os.PathLike[str] | None


def _is_url(p: PathArg) -> bool:
    return isinstance(p, str) and "://" in p and not p.startswith("sqlite:///")


def _fs_path(p: PathArg) -> str | None:
    """A file-system path of an argument (None for None, '' and URLs)."""
    if p is None or _is_url(p):
        return None
    text = os.fspath(p)
    if isinstance(text, str) and text.startswith("sqlite:///"):
        text = text.removeprefix("sqlite:///")
    return text or None


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether two paths name one file: the same resolved path (symbolic links and ``..``
    followed, also for a path that does not exist yet) or, both existing, the same device
    and inode (a hard link)."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        sa, sb = os.stat(a), os.stat(b)
    except OSError:
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def refuse_output_is_input(
    outputs: Iterable[tuple[str, PathArg]], inputs: Iterable[tuple[str, PathArg]]
) -> str | None:
    """The refusal (a message naming both) when an output path resolves to an input (the
    same file, through a symbolic link or a hard link) or two outputs name one file; None
    when every output is distinct. ``outputs`` and ``inputs``: ``(what, path)`` pairs, e.g.
    ``("--out", args.out)``; None and URLs are skipped. Call it in a command's argument
    checks, before anything is opened for writing (exit 2, ``EXIT_USAGE``)."""
    ins = [(w, p) for w, p in ((w, _fs_path(p)) for w, p in inputs) if p is not None]
    seen: list[tuple[str, str]] = []
    for what, raw in outputs:
        p = _fs_path(raw)
        if p is None:
            continue
        for iw, ip in ins:
            if same_file(p, ip):
                how = "" if os.path.realpath(p) == os.path.realpath(ip) else " (a link to it)"
                return (
                    f"{what} {p}: is the input {iw} {ip}{how}; refusing to overwrite an input "
                    "(write to another file)"
                )
        for ow, op in seen:
            if same_file(p, op):
                return f"{what} {p}: is also the output {ow}; give two different files"
        seen.append((what, p))
    return None


def check_writable(
    what: str, path: PathArg, *, directory: bool = False, makes_folders: bool = False
) -> str | None:
    """The refusal when ``path`` cannot be written (its folder missing, not writable or on
    a read-only file system, or the path a directory / not one), without creating it; None
    when it can. ``directory``: ``path`` is a folder that will hold the outputs (created
    when missing); ``makes_folders``: the writer creates missing folders (the MCAP logger,
    the store), so the nearest existing one must be writable."""
    p = _fs_path(path)
    if p is None:
        return None
    if os.path.isdir(p) and not directory:
        return f"{what} {p}: is a directory; expected a file"
    target = p
    if not os.path.exists(p):
        target = os.path.dirname(os.path.abspath(p))
        if not (directory or makes_folders) and not os.path.isdir(target):
            return f"{what} {p}: no such folder {target}"
        while not os.path.exists(target):  # a folder that will be created: its parent
            parent = os.path.dirname(target)
            if parent == target:
                break
            target = parent
        if not os.path.isdir(target):
            return f"{what} {p}: {target} is not a directory"
    elif directory and not os.path.isdir(p):
        return f"{what} {p}: is a file; expected a directory"
    if not os.access(target, os.W_OK):
        import errno

        err = errno.EROFS if _read_only_fs(target) else errno.EACCES
        return f"{what} {p}: cannot write there ({target}: {os.strerror(err)})"
    return None


def _read_only_fs(path: str) -> bool:
    try:
        return bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    except OSError:
        return False


#: outputs whose writer creates missing folders: MCAP logs and the store
_MAKES_FOLDERS = ("--out", "--log", "--store")


def check_outputs(
    outputs: Iterable[tuple[str, PathArg]],
    inputs: Iterable[tuple[str, PathArg]] = (),
    *,
    directories: Iterable[tuple[str, PathArg]] = (),
    makes_folders: Iterable[str] = _MAKES_FOLDERS,
) -> None:
    """A command's output checks, before its work: no output is an input
    (``refuse_output_is_input``) and each can be written (``check_writable``); raises
    ``CommandError`` (exit 2) naming the first that fails. ``directories``: output folders;
    ``makes_folders``: the outputs whose missing folders the writer creates."""
    outputs, directories = list(outputs), list(directories)
    makes = set(makes_folders)
    msg = refuse_output_is_input(outputs + directories, inputs)
    if msg is None:
        for what, p in outputs:
            msg = check_writable(what, p, makes_folders=what in makes)
            if msg is not None:
                break
    if msg is None:
        for what, p in directories:
            msg = check_writable(what, p, directory=True)
            if msg is not None:
                break
    if msg is not None:
        raise CommandError(msg, EXIT_USAGE)


@contextmanager
def writing(what: str, path: PathArg, *, so_far: str | None = None) -> Iterator[None]:
    """Around the code that writes output ``path``: an OSError (disk full, I/O error, the
    folder gone) becomes a ``CommandError`` (exit 5, ``EXIT_IO``) naming the output, its
    cause and what was written before (``so_far``)."""
    try:
        yield
    except OSError as e:
        tail = f"; {so_far}" if so_far else ""
        raise CommandError(
            f"{what} {_fs_path(path) or path}: write failed: {_cause(e)} (the file is "
            f"incomplete){tail}",
            EXIT_IO,
        ) from e
