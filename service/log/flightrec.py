"""The flight record of an MCAP log: which flight (or ground cycle) of which actuator its samples
belong to, and when it started in calendar time (docs/prognostics.md, "From logs to a history").

One MCAP metadata record named ``servowatch.flight`` per actuator and flight, with the string
fields

- ``aircraft``, ``actuator``: the unit (as in the topic ``/fleet/{aircraft}/{actuator}/meas``);
- ``flight``: the flight (or cycle) number, an integer >= 0, counted per unit;
- ``start_unix``: calendar time of the flight's first sample [Unix s, UTC] (optional);
- ``t0``: the sample time ``t`` [s] at ``start_unix`` (optional, default: the first sample's).

A log may hold several records (several actuators, or flights one after the other: the later
record of a unit applies from its ``t0`` on). ``write_flight_log`` writes an acquisition-style
log of one unit's flight with its record (used by the fleet simulator, the tests and the
docs' example).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "FLIGHT_RECORD",
    "MAX_FLIGHT",
    "FlightRecord",
    "flight_records",
    "write_flight_log",
    "log_units",
]

FLIGHT_RECORD = "servowatch.flight"
MAX_FLIGHT = 2**31 - 1
"""Highest flight number taken (a record or ``replay --flight`` above it is refused)."""


@dataclass(frozen=True)
class FlightRecord:
    """One ``servowatch.flight`` record (module docstring)."""

    aircraft: str
    actuator: str
    flight: int
    start_unix: float | None = None
    t0: float | None = None

    @property
    def name(self) -> str:
        """``{aircraft}/{actuator}``."""
        return f"{self.aircraft}/{self.actuator}"

    def to_metadata(self) -> dict[str, str]:
        """The record's string fields."""
        md = {"aircraft": self.aircraft, "actuator": self.actuator, "flight": str(self.flight)}
        if self.start_unix is not None:
            md["start_unix"] = repr(float(self.start_unix))
        if self.t0 is not None:
            md["t0"] = repr(float(self.t0))
        return md

    @classmethod
    def from_metadata(cls, md: Mapping[str, str]) -> FlightRecord:
        """Parse and check a record's fields (ValueError naming the field)."""
        for k in ("aircraft", "actuator", "flight"):
            if not md.get(k):
                raise ValueError(f"{FLIGHT_RECORD}: field {k!r} is missing")
        text = str(md["flight"]).strip()
        if not text.isdigit() or len(text) > 12:  # int() alone takes "1_0", " 7" and 10**4300
            raise ValueError(f"{FLIGHT_RECORD}: flight {md['flight'][:40]!r} is not an integer "
                             f"in 0..{MAX_FLIGHT}")  # fmt: skip
        flight = int(text)
        if flight > MAX_FLIGHT:
            raise ValueError(f"{FLIGHT_RECORD}: flight {flight} is above {MAX_FLIGHT}")
        out: dict[str, float | None] = {}
        for k in ("start_unix", "t0"):
            v = md.get(k)
            if v in (None, ""):
                out[k] = None
                continue
            try:
                x = float(v)
            except (ValueError, TypeError):
                raise ValueError(f"{FLIGHT_RECORD}: {k} {str(v)[:40]!r} is not a number") from None
            if not math.isfinite(x):
                raise ValueError(f"{FLIGHT_RECORD}: {k} must be finite, got {v!r}")
            out[k] = x
        return cls(md["aircraft"], md["actuator"], flight, out["start_unix"], out["t0"])


def flight_records(path: str | Path) -> list[FlightRecord]:
    """The ``servowatch.flight`` records of an MCAP file in file order ([] if none or the file
    is unreadable; a malformed record raises ValueError): through the summary's metadata
    index, or by a scan of the records when the file has no summary (truncated)."""
    from mcap.reader import SeekingReader
    from mcap.records import Metadata
    from mcap.stream_reader import StreamReader

    try:
        fh = open(path, "rb")  # noqa: SIM115 - closed below
    except OSError:
        return []
    with fh:
        mds = None
        try:
            rd = SeekingReader(fh)
            if rd.get_summary() is not None:
                mds = [md for md in rd.iter_metadata() if md.name == FLIGHT_RECORD]
        except Exception:
            mds = None
        if mds is None:
            mds = []
            fh.seek(0)
            try:
                for rec in StreamReader(fh, skip_magic=False, emit_chunks=True).records:
                    if isinstance(rec, Metadata) and rec.name == FLIGHT_RECORD:
                        mds.append(rec)
            except Exception:  # a truncated file: the records read so far
                pass
    try:
        return [FlightRecord.from_metadata(md.metadata) for md in mds]
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None


def log_units(path: str | Path) -> list[str]:
    """``{aircraft}/{actuator}`` of each ``/fleet/{aircraft}/{actuator}/meas`` topic of an
    MCAP log (from its summary's channels; a scan of the records when it has none)."""
    from mcap.reader import make_reader

    topics: set[str] = set()
    try:
        with open(path, "rb") as fh:
            summ = make_reader(fh).get_summary()
        if summ is not None:
            topics = {c.topic for c in summ.channels.values()}
    except Exception:
        topics = set()
    if not topics:
        from service.log import read_log

        topics = {topic for topic, _, _ in read_log(path)}
    out = set()
    for topic in topics:
        parts = topic.split("/")
        if len(parts) == 5 and parts[0] == "" and parts[1] == "fleet" and parts[4] == "meas":
            out.add(f"{parts[2]}/{parts[3]}")
    return sorted(out)


def write_flight_log(
    path: str | Path,
    record: FlightRecord,
    t: NDArray,
    channels: Mapping[str, NDArray],
) -> Path:
    """An acquisition-style log of one flight: ``record`` as ``servowatch.flight`` metadata,
    then the samples on ``/fleet/{aircraft}/{actuator}/meas`` (``t`` and each channel of
    ``models.channels.SENSORS`` given, one message per sample)."""
    from models.channels import SENSORS
    from service.log import McapLogger

    t = np.asarray(t, float)
    names = ("t", *[k for k in SENSORS if k in channels])
    vals = np.column_stack([t] + [np.asarray(channels[k], float) for k in names[1:]])
    topic = f"/fleet/{record.aircraft}/{record.actuator}/meas"
    with McapLogger(path, background_flush=False, flush_s=1e9) as lg:
        lg.add_metadata(FLIGHT_RECORD, record.to_metadata())
        lg.log_block(topic, t, names, vals)
    return Path(path)
