"""MCAP logging: the writer, the protobuf rows, the streaming and column-block readers.

``writer`` (:class:`McapLogger`: schemas, rotation, the flush thread), ``rows`` (the protobuf
rows of a fixed layout, decision 0011), ``reader`` (:func:`read_log`, truncation-tolerant),
``blocks`` (:func:`read_blocks`, :class:`LogBlock`), ``codec`` (numba kernels: the chunk scan
and the JSON parser of older logs and of events, imported on first use). mcap's private APIs are used only through
:mod:`service.compat.mcap`.
Also ``flightrec`` (the ``servowatch.flight`` record), ``proclog`` (the child log process)
and ``setup`` (the one log-line format of every process: JSON, plain text, journald).
May import models, compat and the loose utilities only.
"""

from service.log.blocks import LogBlock, read_blocks
from service.log.reader import (
    CorruptChunkWarning,
    LogReadStats,
    TruncatedLogWarning,
    read_log,
    read_log_files,
    rotated_files,
)
from service.log.writer import McapLogger, json_schema_for, row_schema

__all__ = [
    "McapLogger",
    "LogBlock",
    "read_blocks",
    "read_log",
    "read_log_files",
    "rotated_files",
    "json_schema_for",
    "row_schema",
    "TruncatedLogWarning",
    "CorruptChunkWarning",
    "LogReadStats",
]
