"""Shared fixtures: ``store_url`` runs a store test on SQLite and on PostgreSQL.

The PostgreSQL side starts one throwaway cluster for the session when the server binaries
are installed (PATH or /usr/lib/postgresql/*/bin) and gives each test a fresh database;
without them those tests skip and the run says so in its summary (they fail instead when
``SERVOWATCH_REQUIRE_PG=1``, as in CI).
"""

from __future__ import annotations

import os
import subprocess
from typing import Any

import pytest

_PG: dict[str, Any] = {"cluster": None, "reason": None, "skipped": 0, "used": 0}


@pytest.fixture(scope="session", autouse=True)
def _default_store(tmp_path_factory):
    """``servowatch run`` writes a health store by default: keep it out of the work tree."""
    if "SERVOWATCH_STORE" in os.environ:
        yield
        return
    os.environ["SERVOWATCH_STORE"] = str(tmp_path_factory.mktemp("store") / "health.sqlite")
    try:
        yield
    finally:
        os.environ.pop("SERVOWATCH_STORE", None)


@pytest.fixture(scope="session")
def pg_cluster():
    """The session's throwaway PostgreSQL cluster, or None when it cannot be started
    (or ``SERVOWATCH_TEST_PG=0`` turns it off)."""
    if os.environ.get("SERVOWATCH_TEST_PG") == "0":
        _PG["reason"] = "turned off by SERVOWATCH_TEST_PG=0"
        yield None
        return
    try:
        import psycopg  # noqa: F401

        from service.store.pgtemp import ClusterUnavailableError, TempCluster

        cluster = TempCluster()
        cluster.start()
    except ImportError as e:
        _PG["reason"] = f"psycopg is not installed ({e})"
        yield None
        return
    except (ClusterUnavailableError, OSError, subprocess.SubprocessError) as e:
        _PG["reason"] = str(e)
        yield None
        return
    _PG["cluster"] = cluster
    try:
        yield cluster
    finally:
        cluster.stop()


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request, tmp_path) -> str:
    """A fresh, empty store: a SQLite file path or a PostgreSQL database URL."""
    if request.param == "sqlite":
        return str(tmp_path / "health.sqlite")
    cluster = request.getfixturevalue("pg_cluster")
    if cluster is None:
        if os.environ.get("SERVOWATCH_REQUIRE_PG") == "1":
            pytest.fail(f"PostgreSQL required (SERVOWATCH_REQUIRE_PG=1): {_PG['reason']}")
        _PG["skipped"] += 1
        pytest.skip(f"PostgreSQL tests skipped: {_PG['reason']}")
    _PG["used"] += 1
    return cluster.create_database()


@pytest.fixture
def net():
    """A Zenoh router in the test process and a client session through it
    (``tests.test_service_e2e.Net``), closed with every process it started."""
    from tests.test_service_e2e import Net

    n = Net()
    yield n
    n.close()


def pytest_terminal_summary(terminalreporter) -> None:
    if _PG["skipped"]:
        terminalreporter.write_sep(
            "=", f"PostgreSQL tests SKIPPED ({_PG['skipped']}): {_PG['reason']}", yellow=True
        )
    elif _PG["used"]:
        c = _PG["cluster"]
        where = f" (throwaway cluster from {c.bindir})" if c is not None else ""
        terminalreporter.write_line(f"PostgreSQL store tests ran: {_PG['used']}{where}")
