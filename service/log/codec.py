"""Numba kernels for block MCAP I/O of flat JSON messages (used by :mod:`service.log`): this
module is their interface; the kernels are in :mod:`service.log.codec_write` (encoding),
:mod:`service.log.codec_read` (decoding) and :mod:`service.log.codec_arith` (shared arithmetic).

Writing (:func:`encode_records`): rows of a float64 array formatted exactly like
``json.JSONEncoder(separators=(",", ":"))`` formats ``{name: float_or_int_or_None}`` (floats as
``float.__repr__``: shortest round-trip digits by the Ryu algorithm, Python's fixed/exponent
layout) and packed straight into MCAP Message records.

Reading (:func:`scan_records`, :func:`parse_objects`): the records of a decompressed chunk
without a Python loop, then a run of flat JSON objects with the same key bytes into an (N, F)
float64 array. Numbers are converted with Clinger's fast path or the Eisel-Lemire algorithm,
which are correctly rounded (the result equals ``float(text)``); anything else (more than 19
significant digits, nested values, escapes, NaN/Infinity literals, differing keys) makes
:func:`parse_objects` report failure so the caller can fall back to ``json.loads``.

Algorithms (implemented here from the papers; the tables are computed at import):

* Ryu: Ulf Adams, "Ryu: fast float-to-string conversion", Proceedings of the 39th ACM
  SIGPLAN Conference on Programming Language Design and Implementation (PLDI 2018),
  pp. 270-282, doi:10.1145/3192366.3192369. The shortest digits that round-trip; the layout
  around them (fixed or exponent form, ``1e+16``, ``-0.0``) is CPython's ``float.__repr__``.
* Eisel-Lemire: Daniel Lemire, "Number parsing at a gigabyte per second", Software: Practice
  and Experience 51(8), 2021, pp. 1700-1727, doi:10.1002/spe.2984 (the algorithm of Michael
  Eisel); with William D. Clinger's exact fast path, "How to read floating point numbers
  accurately", PLDI 1990.

Why byte-identical with ``json.dumps``: see docs/messages.md ("MCAP log"). In short, one
message logged per row by :meth:`McapLogger.log_block` and by :meth:`McapLogger.log` must give
the same file, so the tests can hold the compiled encoder to the standard library byte for
byte, and a replay's log compares with the daemon's by bytes or hash.

All kernels are ``@njit(cache=True)``: the first call compiles (or loads the cache; a cold
compile takes some seconds, :func:`warm_up` does it ahead). The kernels that allocate nothing are
compiled without numba's reference counting (its atomic incref/decref on every array argument
otherwise costs more than the parsing).
"""

from __future__ import annotations

import numpy as np

from service.log.codec_arith import MSG_OPCODE
from service.log.codec_read import parse_number, parse_objects, scan_records
from service.log.codec_write import RowFormat, encode_records, format_float, row_format

__all__ = [
    "MSG_OPCODE",
    "warm_up",
    "RowFormat",
    "row_format",
    "encode_records",
    "scan_records",
    "parse_objects",
    "parse_number",
    "format_float",
]


def warm_up() -> None:
    """Compile (or load from the cache) the kernels of the write and read paths."""
    fmt = row_format(("seq", "x"), frozenset({"seq"}))
    recs, ends = encode_records(fmt, np.array([[1.0, 0.5]]), 1, 0, np.zeros(1, np.int64))
    ops, starts, lens, _cids, _lts = scan_records(recs)
    parse_objects(recs, starts + 22, lens - 22)
