"""Schema of the health store as an ordered list of migrations.

Each migration is applied once, in order, in one transaction that also records its version
in ``schema_migrations``. The DDL is portable: SQLite and PostgreSQL both take these types
(TEXT, DOUBLE PRECISION, BIGINT, INTEGER). JSON documents are stored as TEXT.
"""

from __future__ import annotations

__all__ = ["MIGRATIONS", "LATEST_VERSION", "RECENT_WINDOW", "RECOMPUTE_TRENDS", "REBUILD_SUMMARIES"]

# periods kept in each actuator's summary row for the trend (the fleet query reads only these)
RECENT_WINDOW = 32

# data step of a migration: recompute every summary row's trend from its ``recent`` window
RECOMPUTE_TRENDS = "-- recompute trends"
# data step: rebuild every summary row along its unit's life order (``lifeorder.life_order``)
REBUILD_SUMMARIES = "-- rebuild summaries"

_V1: tuple[str, ...] = (
    """CREATE TABLE actuators (
        name TEXT PRIMARY KEY,
        created_s DOUBLE PRECISION NOT NULL
    )""",
    """CREATE TABLE baselines (
        actuator TEXT NOT NULL REFERENCES actuators(name),
        version INTEGER NOT NULL,
        source TEXT NOT NULL,
        created_s DOUBLE PRECISION NOT NULL,
        baseline TEXT NOT NULL,
        figures TEXT NOT NULL,
        PRIMARY KEY (actuator, version)
    )""",
    # the key (actuator, start_t, source) also serves "periods of one actuator by start_t"
    """CREATE TABLE periods (
        actuator TEXT NOT NULL REFERENCES actuators(name),
        start_t DOUBLE PRECISION NOT NULL,
        source TEXT NOT NULL,
        end_t DOUBLE PRECISION NOT NULL,
        op_time_s DOUBLE PRECISION NOT NULL,
        samples BIGINT NOT NULL,
        flight BIGINT,
        c_lk_mean DOUBLE PRECISION,
        c_lk_sigma DOUBLE PRECISION,
        c_lk_ratio DOUBLE PRECISION,
        observable_samples BIGINT NOT NULL,
        p_sr_mean DOUBLE PRECISION,
        p_sr_min DOUBLE PRECISION,
        i_b_mean DOUBLE PRECISION,
        nis_mean DOUBLE PRECISION,
        nis_in_band DOUBLE PRECISION,
        alarms BIGINT NOT NULL,
        bad_samples BIGINT NOT NULL,
        dropped BIGINT NOT NULL,
        PRIMARY KEY (actuator, start_t, source)
    )""",
    """CREATE TABLE alarms (
        actuator TEXT NOT NULL REFERENCES actuators(name),
        t DOUBLE PRECISION NOT NULL,
        kind TEXT NOT NULL,
        source TEXT NOT NULL,
        value DOUBLE PRECISION,
        PRIMARY KEY (actuator, t, kind, source)
    )""",
    """CREATE TABLE rul (
        actuator TEXT PRIMARY KEY REFERENCES actuators(name),
        updated_s DOUBLE PRECISION NOT NULL,
        rul TEXT NOT NULL
    )""",
    # one row per actuator, updated in the same transaction as its periods/alarms/baselines
    """CREATE TABLE summary (
        actuator TEXT PRIMARY KEY REFERENCES actuators(name),
        n_periods BIGINT NOT NULL DEFAULT 0,
        op_time_s DOUBLE PRECISION NOT NULL DEFAULT 0,
        samples BIGINT NOT NULL DEFAULT 0,
        alarms BIGINT NOT NULL DEFAULT 0,
        bad_samples BIGINT NOT NULL DEFAULT 0,
        dropped BIGINT NOT NULL DEFAULT 0,
        first_start_t DOUBLE PRECISION,
        last_start_t DOUBLE PRECISION,
        last_period TEXT,
        recent TEXT NOT NULL DEFAULT '[]',
        alarm_events BIGINT NOT NULL DEFAULT 0,
        last_alarm_t DOUBLE PRECISION,
        last_alarm_kind TEXT,
        baseline_version INTEGER NOT NULL DEFAULT 0
    )""",
)

# the C_Lk-ratio trend kept in the summary row (the fleet query then parses no history);
# rows written before it get theirs from ``recent`` when the migration runs
_V2: tuple[str, ...] = (
    "ALTER TABLE summary ADD COLUMN trend_n INTEGER NOT NULL DEFAULT 0",
    "ALTER TABLE summary ADD COLUMN trend_slope_per_h DOUBLE PRECISION",
    "ALTER TABLE summary ADD COLUMN trend_change DOUBLE PRECISION",
    "ALTER TABLE summary ADD COLUMN trend_label TEXT NOT NULL DEFAULT 'unknown'",
    RECOMPUTE_TRENDS,
)

# calendar time of a period's first sample (Unix s; None where the log does not give it)
_V3: tuple[str, ...] = ("ALTER TABLE periods ADD COLUMN start_unix DOUBLE PRECISION",)

# what each replayed log stored per unit (docs/store.md, "What identifies a log"): its
# accepted samples (a longer ingest of the same source supersedes a shorter one), the file
# name it was first read under (life order of logs without calendar time) and whether its
# flights follow the gap rule ('gap', renumbered after each ingest) or the log ('log')
_V4: tuple[str, ...] = (
    """CREATE TABLE log_sources (
        actuator TEXT NOT NULL REFERENCES actuators(name),
        source TEXT NOT NULL,
        samples BIGINT NOT NULL,
        name TEXT NOT NULL,
        flights TEXT NOT NULL,
        PRIMARY KEY (actuator, source)
    )""",
)

# what wears the seals and the spool, per period (service.store.records.USAGE_FIELDS; NULL in
# the periods stored before), and the running totals of the summary row that the fleet view
# divides by the operating time they cover: over the periods with usage (travel, reversals)
# and over those with a load figure (load-weighted travel)
_V5: tuple[str, ...] = (
    "ALTER TABLE periods ADD COLUMN usage_travel_m DOUBLE PRECISION",
    "ALTER TABLE periods ADD COLUMN usage_load_travel_j DOUBLE PRECISION",
    "ALTER TABLE periods ADD COLUMN usage_load2_travel_n2m DOUBLE PRECISION",
    "ALTER TABLE periods ADD COLUMN usage_reversals DOUBLE PRECISION",
    "ALTER TABLE periods ADD COLUMN usage_loaded_s DOUBLE PRECISION",
    "ALTER TABLE periods ADD COLUMN usage_pressurised_s DOUBLE PRECISION",
    "ALTER TABLE summary ADD COLUMN usage_periods BIGINT NOT NULL DEFAULT 0",
    "ALTER TABLE summary ADD COLUMN usage_op_time_s DOUBLE PRECISION NOT NULL DEFAULT 0",
    "ALTER TABLE summary ADD COLUMN usage_travel_m DOUBLE PRECISION NOT NULL DEFAULT 0",
    "ALTER TABLE summary ADD COLUMN usage_reversals DOUBLE PRECISION NOT NULL DEFAULT 0",
    "ALTER TABLE summary ADD COLUMN usage_load_op_time_s DOUBLE PRECISION NOT NULL DEFAULT 0",
    "ALTER TABLE summary ADD COLUMN usage_load_travel_j DOUBLE PRECISION NOT NULL DEFAULT 0",
)

# the pooled C_Lk reading of each period and its sigma (service.store.records.POOLED_FIELDS;
# NULL in the periods stored before: their c_lk_ratio stays the median reading it was)
_V6: tuple[str, ...] = (
    "ALTER TABLE periods ADD COLUMN c_lk_pooled DOUBLE PRECISION",
    "ALTER TABLE periods ADD COLUMN c_lk_pooled_sigma DOUBLE PRECISION",
)

# a log's identity from all of its samples and one life order (decision records 0033 and
# 0034; docs/store.md, "What identifies a log"): per replayed log and unit its stream
# identity (``service.store.identity.StreamId`` as JSON; NULL: stored before, identified by its
# first sample, adopted when the log is replayed again) and its periods' start_t in the log's
# sample order; per summary row where the unit stands in that order (the key of its last
# period), its life axis, first flight and flight count, and its latest observable C_Lk ratio.
# The data step rebuilds every summary row along the life order.
_V7: tuple[str, ...] = (
    "ALTER TABLE log_sources ADD COLUMN identity TEXT",
    "ALTER TABLE log_sources ADD COLUMN sample_order TEXT",
    "ALTER TABLE summary ADD COLUMN last_key TEXT",
    "ALTER TABLE summary ADD COLUMN life_axis TEXT NOT NULL DEFAULT 'hours'",
    "ALTER TABLE summary ADD COLUMN first_flight BIGINT",
    "ALTER TABLE summary ADD COLUMN n_flights BIGINT NOT NULL DEFAULT 0",
    "ALTER TABLE summary ADD COLUMN last_ratio DOUBLE PRECISION",
    REBUILD_SUMMARIES,
)

# where a unit's stored flights stand against its life order, for the incremental
# renumbering (docs/store.md, "What a re-run does"; decision record 0044): the life-order
# key from which the stored flights may differ from a renumbering over the whole history
# (``renumber_from``: NULL, none may; '[]', before every period: the next write renumbers
# the whole history, as every row stored before this migration does once) and the flight
# gap they were numbered with; how many of its periods are the daemon's live ones (a log
# of the daemon looks for those it replaces only when there are); and indexes on the periods and alarms of one log of a unit
# (a supersede's deletes, the flights of a log) that no longer read the unit's history
_V8: tuple[str, ...] = (
    "ALTER TABLE summary ADD COLUMN renumber_from TEXT DEFAULT '[]'",
    "ALTER TABLE summary ADD COLUMN flight_gap_s DOUBLE PRECISION",
    "ALTER TABLE summary ADD COLUMN live_periods BIGINT NOT NULL DEFAULT 0",
    "CREATE INDEX periods_by_source ON periods (actuator, source)",
    "CREATE INDEX alarms_by_source ON alarms (actuator, source)",
    # a unit's periods by their calendar end: the periods a new log overlaps in calendar
    # time (``ingest._calendar_overlaps``) without reading the unit's history
    "CREATE INDEX periods_by_end_unix ON periods (actuator, (start_unix + (end_t - start_t)))",
    REBUILD_SUMMARIES,
)

# (version, description, statements): append only; never edit a released migration. A
# statement is SQL, or RECOMPUTE_TRENDS (a data step run by the store in the same transaction)
MIGRATIONS: tuple[tuple[int, str, tuple[str, ...]], ...] = (
    (1, "actuators, baselines, periods, alarms, rul, per-actuator summary", _V1),
    (2, "C_Lk-ratio trend columns in the summary", _V2),
    (3, "calendar time of each period", _V3),
    (4, "replayed logs per unit: samples, name, flight rule", _V4),
    (
        5,
        "usage per period (travel, load-weighted travel, reversals, time under load and at pressure)",
        _V5,
    ),
    (6, "pooled C_Lk reading of each period and its sigma", _V6),
    (7, "stream identity of replayed logs, one life order in the summary", _V7),
    (
        8,
        "incremental renumbering: where the stored flights stand; per-log, calendar-end indexes",
        _V8,
    ),
)

LATEST_VERSION = MIGRATIONS[-1][0]
