"""Health store: actuators, versioned baselines, operating periods, alarms and RUL summaries.

``open_store(url_or_path)`` opens a SQLite file (default, embedded, WAL) or a PostgreSQL
database (``postgresql://...``). See docs/store.md.
May import models, compat and the loose utilities only.
"""

from __future__ import annotations

from service.paths import DEFAULT_STORE, store_of
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


def default_store() -> str:
    """``$SERVOWATCH_STORE`` if set, else the ``store`` of the config file the search finds
    (``service.paths``: ``$SERVOWATCH_CONFIG``, the user's, the system's), else
    ``servowatch-data/health.sqlite``."""
    return store_of()[0]
