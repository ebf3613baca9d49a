"""Health store: actuators, versioned baselines, operating periods, alarms and RUL summaries.

``open_store(url_or_path)`` opens a SQLite file (default, embedded, WAL) or a PostgreSQL
database (``postgresql://...``). See docs/store.md.
May import models, compat and the loose utilities only.
"""

from __future__ import annotations

import os
from pathlib import Path

from service.store.health import HealthStore, StoreError, describe_url, open_store, trend_of
from service.store.records import (
    ActuatorKey,
    AlarmEvent,
    BaselineRecord,
    Period,
    check_actuator,
)

__all__ = [
    "ActuatorKey",
    "AlarmEvent",
    "BaselineRecord",
    "DEFAULT_STORE",
    "HealthStore",
    "Period",
    "StoreError",
    "check_actuator",
    "default_store",
    "describe_url",
    "open_store",
    "trend_of",
]

# the daemon's data directory holds the embedded store unless told otherwise
DEFAULT_STORE = Path("servowatch-data") / "health.sqlite"


def default_store() -> str:
    """``$SERVOWATCH_STORE`` if set, else ``servowatch-data/health.sqlite``."""
    return os.environ.get("SERVOWATCH_STORE") or str(DEFAULT_STORE)
