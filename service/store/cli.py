"""Command-line helpers for the store: the ``--store`` option and opening it with clear
errors (exit 2), shared by every command that uses the store."""

from __future__ import annotations

import argparse

from service.store import HealthStore, StoreError, default_store, open_store
from service.store.health import READ_TIMEOUT_S

__all__ = ["add_store_argument", "open_store_arg", "store_path_arg"]


def add_store_argument(p: argparse.ArgumentParser) -> None:
    """``--store PATH|URL`` (default ``$SERVOWATCH_STORE`` or servowatch-data/health.sqlite)."""
    p.add_argument(
        "--store",
        default=None,
        metavar="PATH|URL",
        help="health store: a SQLite file path or a postgresql:// URL "
        "(default $SERVOWATCH_STORE, else servowatch-data/health.sqlite)",
    )


def store_path_arg(args: argparse.Namespace) -> str:
    """``args.store`` or the default store (a path or a URL)."""
    return args.store if args.store is not None else default_store()


def open_store_arg(
    args: argparse.Namespace, *, create: bool, read_only: bool = False
) -> HealthStore:
    """Open ``args.store`` (or the default); raises ``StoreError`` naming ``--store``.
    ``read_only``: the reading commands' open (never created, never migrated, never
    written; a writer's lock waited for at most ``READ_TIMEOUT_S``)."""
    target = store_path_arg(args)
    try:
        if read_only:
            return open_store(target, read_only=True, timeout_s=READ_TIMEOUT_S)
        return open_store(target, create=create)
    except StoreError as e:
        raise StoreError(f"--store: {e}") from e
