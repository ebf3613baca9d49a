"""MCAP logging: the writer, the streaming and column-block readers, the compiled JSON codec.

``writer`` (:class:`McapLogger`: schemas, rotation, the flush thread), ``reader``
(:func:`read_log`, truncation-tolerant), ``blocks`` (:func:`read_blocks`, :class:`LogBlock`),
``codec`` (numba kernels, imported on first use). mcap's private APIs are used only through
:mod:`service.compat.mcap`.
"""

from service.log.blocks import LogBlock, read_blocks
from service.log.reader import (
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
    "LogReadStats",
]
