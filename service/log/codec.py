"""Numba kernels for reading MCAP chunks and the JSON messages of older logs (used by
:mod:`service.log`): this module is their interface; the kernels are in
:mod:`service.log.codec_read` and :mod:`service.log.codec_arith` (shared arithmetic).

:func:`scan_records` finds the records of a decompressed chunk without a Python loop (every
log: the protobuf rows are then gathered by :mod:`service.log.rows`). :func:`parse_objects`
reads a run of flat JSON objects with the same key bytes into an (N, F) float64 array: the
rows of logs written before decision 0011 (docs/decisions/0011-binary-log-rows.md), and the
JSON messages (events) of every log. Numbers are converted with Clinger's fast path or the
Eisel-Lemire algorithm, which are correctly rounded (the result equals ``float(text)``);
anything else (more than 19 significant digits, nested values, escapes, NaN/Infinity
literals, differing keys) makes :func:`parse_objects` report failure so the caller can fall
back to ``json.loads``. Nothing writes JSON rows any more: the compiled encoder that wrote
them byte-identical with ``json.dumps`` was retired with decision 0011.

Algorithms (implemented here from the papers; the tables are computed at import):

* Eisel-Lemire: Daniel Lemire, "Number parsing at a gigabyte per second", Software: Practice
  and Experience 51(8), 2021, pp. 1700-1727, doi:10.1002/spe.2984 (the algorithm of Michael
  Eisel); with William D. Clinger's exact fast path, "How to read floating point numbers
  accurately", PLDI 1990.

All kernels are ``@njit(cache=True)``: the first call compiles (or loads the cache; a cold
compile takes some seconds, :func:`warm_up` does it ahead). The kernels that allocate nothing
are compiled without numba's reference counting (its atomic incref/decref on every array
argument otherwise costs more than the parsing).
"""

from __future__ import annotations

import struct

import numpy as np

from service.log.codec_arith import MSG_OPCODE
from service.log.codec_read import parse_number, parse_objects, scan_records

__all__ = [
    "MSG_OPCODE",
    "warm_up",
    "json_records",
    "scan_records",
    "parse_objects",
    "parse_number",
]

_MSG = struct.Struct("<BQHIQQ")


def json_records(datas: list[bytes], channel_id: int = 1) -> np.ndarray:
    """MCAP Message records of ``datas`` (log time k, sequence k) as uint8: what a chunk
    of a JSON log holds (for the warm-up and the tests)."""
    out = b"".join(
        _MSG.pack(MSG_OPCODE, 22 + len(d), channel_id, k, k, k) + d for k, d in enumerate(datas)
    )
    return np.frombuffer(out, np.uint8)


def warm_up() -> None:
    """Compile (or load from the cache) the kernels of the read path."""
    recs = json_records([b'{"seq":1,"x":0.5}'])
    ops, starts, lens, _cids, _lts = scan_records(recs)
    parse_objects(recs, starts + 22, lens - 22)
