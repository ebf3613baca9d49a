"""Where a station's state lives (docs/cli.md, "Where state lives"): the config file every
command reads, and the store and logs it resolves.

The config file, the first of:

1. ``--config FILE`` (the commands that take it);
2. ``$SERVOWATCH_CONFIG``;
3. the user's: ``$XDG_CONFIG_HOME/servowatch/servowatch.toml`` (``~/.config/...``);
4. the system's: ``/etc/servowatch/servowatch.toml``;

else none (every setting at its default). A file named by 1 or 2 must exist; 3 and 4 are
used when they exist. ``SERVOWATCH_*`` variables override the file's settings.

The health store: ``--store``, else ``$SERVOWATCH_STORE``, else the config's ``store``, else
``servowatch-data/health.sqlite``; the logs: the config's ``log_dir``, else
``servowatch-data/logs`` (relative paths: to the working directory).
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Mapping
from pathlib import Path

__all__ = [
    "CONFIG_ENV",
    "DEFAULT_STORE",
    "DEFAULT_LOG_DIR",
    "SYSTEM_CONFIG",
    "config_search",
    "find_config",
    "store_of",
    "user_config",
]

CONFIG_ENV = "SERVOWATCH_CONFIG"
SYSTEM_CONFIG = Path("/etc/servowatch/servowatch.toml")
DEFAULT_STORE = Path("servowatch-data") / "health.sqlite"
DEFAULT_LOG_DIR = Path("servowatch-data") / "logs"


def user_config(env: Mapping[str, str] | None = None) -> Path:
    """``$XDG_CONFIG_HOME/servowatch/servowatch.toml`` (default ``~/.config``)."""
    env = os.environ if env is None else env
    base = env.get("XDG_CONFIG_HOME") or str(Path(env.get("HOME") or Path.home()) / ".config")
    return Path(base) / "servowatch" / "servowatch.toml"


def config_search(
    flag: str | Path | None = None, env: Mapping[str, str] | None = None
) -> list[tuple[str, Path]]:
    """The search order as (where, path): the flag, the variable, the user's and the
    system's file (module docstring); those not given are left out."""
    env = os.environ if env is None else env
    out: list[tuple[str, Path]] = []
    if flag:
        out.append(("--config", Path(flag)))
    if env.get(CONFIG_ENV):
        out.append((f"${CONFIG_ENV}", Path(env[CONFIG_ENV])))
    out.append(("the user's config", user_config(env)))
    out.append(("the system's config", SYSTEM_CONFIG))
    return out


def find_config(
    flag: str | Path | None = None, env: Mapping[str, str] | None = None
) -> tuple[Path | None, str]:
    """The config file a command reads and where it came from (``--config``,
    ``$SERVOWATCH_CONFIG``, the user's or the system's config), or ``(None, "defaults")``.
    A file named by the flag or the variable is returned even if missing (the reader then
    says it cannot read it); the user's and the system's only when they exist."""
    for where, p in config_search(flag, env):
        if where.startswith(("--", "$")) or p.is_file():
            return p, where
    return None, "defaults"


def store_of(flag: str | None = None, env: Mapping[str, str] | None = None) -> tuple[str, str]:
    """The health store a command uses and where that came from: ``--store`` (``flag``),
    ``$SERVOWATCH_STORE``, the found config's ``store``, or the default."""
    env = os.environ if env is None else env
    if flag:
        return flag, "--store"
    if env.get("SERVOWATCH_STORE"):
        return env["SERVOWATCH_STORE"], "$SERVOWATCH_STORE"
    path, where = find_config(env=env)
    if path is not None:
        try:
            data = tomllib.loads(path.read_text())
        except (OSError, tomllib.TOMLDecodeError):
            data = {}
        store = data.get("store")
        if isinstance(store, str) and store.strip():
            return store, f"{where} {path}"
    return str(DEFAULT_STORE), "the default"
