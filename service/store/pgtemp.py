"""A throwaway PostgreSQL cluster for tests and benchmarks (never for production data).

``find_pg_bin()`` looks for ``initdb``/``pg_ctl`` on PATH, then in
``/usr/lib/postgresql/*/bin`` (newest first). ``TempCluster`` runs ``initdb`` in a temporary
directory and ``pg_ctl start`` on 127.0.0.1 at a free port (socket in the same directory);
as root both run as the ``postgres`` system user (``initdb`` refuses root). ``stop()`` stops
the server and deletes the directory.
"""

from __future__ import annotations

import os
import pwd
import re
import shutil
import socket
import subprocess
import tempfile
import uuid
from pathlib import Path

__all__ = ["find_pg_bin", "TempCluster", "ClusterUnavailableError"]


class ClusterUnavailableError(RuntimeError):
    """No PostgreSQL server binaries, or they cannot be run here."""


def find_pg_bin() -> Path | None:
    """Directory holding ``initdb`` and ``pg_ctl``, or None."""
    on_path = shutil.which("initdb")
    if on_path and shutil.which("pg_ctl"):
        return Path(on_path).resolve().parent

    def version(p: Path) -> tuple[int, ...]:
        return tuple(int(x) for x in re.findall(r"\d+", p.parent.name)) or (0,)

    cands = sorted(Path("/usr/lib/postgresql").glob("*/bin"), key=version, reverse=True)
    for d in cands:
        if (d / "initdb").exists() and (d / "pg_ctl").exists():
            return d
    return None


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class TempCluster:
    """A PostgreSQL cluster in a temporary directory; ``url`` after ``start()``."""

    def __init__(self, bindir: Path | None = None, settings: dict[str, str] | None = None):
        self.bindir = bindir or find_pg_bin()
        if self.bindir is None:
            raise ClusterUnavailableError(
                "PostgreSQL server binaries (initdb, pg_ctl) not found on PATH or in "
                "/usr/lib/postgresql/*/bin"
            )
        self.settings = {"fsync": "off", "synchronous_commit": "off", "full_page_writes": "off"}
        self.settings.update(settings or {})
        self.root: Path | None = None
        self.port = 0
        self.url = ""
        self._prefix: list[str] = []

    def _run(self, *args: str, timeout: float = 120.0) -> None:
        cmd = [*self._prefix, *args]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        if r.returncode != 0:
            raise ClusterUnavailableError(
                f"{Path(args[0]).name} failed ({r.returncode}): {(r.stderr or r.stdout).strip()}"
            )

    def start(self) -> str:
        """initdb + start; returns the URL of its ``postgres`` database."""
        self.root = Path(tempfile.mkdtemp(prefix="servowatch-pg-"))
        data = self.root / "data"
        try:
            if os.geteuid() == 0:
                try:
                    pw = pwd.getpwnam("postgres")
                except KeyError:
                    raise ClusterUnavailableError(
                        "running as root and there is no 'postgres' system user to run initdb"
                    ) from None
                runuser = shutil.which("runuser")
                if runuser is None:
                    raise ClusterUnavailableError("running as root and runuser is not installed")
                os.chown(self.root, pw.pw_uid, pw.pw_gid)
                self._prefix = [runuser, "-u", "postgres", "--"]
            self._run(
                str(self.bindir / "initdb"),
                "-D", str(data), "-U", "postgres", "-A", "trust", "-E", "UTF8",
                "--locale=C", "--no-sync",
            )  # fmt: skip
            self.port = _free_port()
            opts = [f"-p {self.port}", "-h 127.0.0.1", f"-k {self.root}"]
            opts += [f"-c {k}={v}" for k, v in self.settings.items()]
            self._run(
                str(self.bindir / "pg_ctl"),
                "-D", str(data), "-l", str(self.root / "server.log"), "-w", "-t", "60",
                "-o", " ".join(opts), "start",
            )  # fmt: skip
        except BaseException:
            self._cleanup()
            raise
        self.url = f"postgresql://postgres@127.0.0.1:{self.port}/postgres"
        return self.url

    def create_database(self, name: str | None = None) -> str:
        """A new empty database; returns its URL."""
        import psycopg

        name = name or f"t_{uuid.uuid4().hex[:12]}"
        if not re.fullmatch(r"[a-z_][a-z0-9_]*", name):
            raise ValueError(f"database name: expected [a-z_][a-z0-9_]*, got {name!r}")
        with psycopg.connect(self.url, autocommit=True) as c:
            c.execute(f"CREATE DATABASE {name}")
        return f"postgresql://postgres@127.0.0.1:{self.port}/{name}"

    def stop(self) -> None:
        """Stop the server and delete its directory (idempotent)."""
        if self.root is None:
            return
        data = self.root / "data"
        if (data / "postmaster.pid").exists():
            try:
                self._run(str(self.bindir / "pg_ctl"), "-D", str(data), "-m", "fast", "-w", "stop")
            except (ClusterUnavailableError, subprocess.TimeoutExpired):
                self._run(str(self.bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop")
        self._cleanup()

    def _cleanup(self) -> None:
        if self.root is not None:
            shutil.rmtree(self.root, ignore_errors=True)
            self.root = None

    def __enter__(self) -> TempCluster:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
