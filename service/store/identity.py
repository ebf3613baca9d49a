"""A unit's sample stream identified by all of its samples (docs/store.md, "What identifies a
log"; decision record 0033).

Each accepted sample (time and the seven channels, 8 float64, bytes exact) is mixed into a
64-bit value ``h`` (``sample_mix``). A sample whose ``h`` has its low ``BLOCK_BITS`` bits
zero ends a **block** (content-defined: about one sample in 256), so a block's bounds depend
on the samples alone, not on where a file starts or was cut. A stream is a list of **runs**
(a corrupt chunk skipped in the middle of a log starts a new run); each run is kept as

- ``d``, ``n``: a digest (BLAKE2b-128) over its blocks' digests in order (so of all of its
  bytes) and its sample count;
- ``head``: the ``h`` of its first block (through its first block-ending sample; the whole
  run when no sample ends a block);
- ``blocks``: ``[digest, count]`` of each block after the first that ends at a block-ending
  sample (a **closed** block: the same samples give it in any log that holds them);
- ``tail``: the ``h`` of the samples after its last block-ending sample.

With these, while a new log is read (``StreamDigest``), a stored stream is found **within**
it exactly: its head ends the new log's block at the same block-ending sample, its closed
blocks follow, its tail starts the next block (``h`` compared sample by sample, the blocks by
digest). A new log is found within a stored stream by its closed blocks, and its two edge
blocks compared sample by sample where they fall on the stored stream's head or tail, by
count elsewhere (``within``: the one place where less than a block, at a log's edges, is
judged by length; ``Relation.exact``). Equal streams have equal run digests.
"""

from __future__ import annotations

import base64
import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "BLOCK_BITS",
    "StreamDigest",
    "StreamId",
    "Relation",
    "sample_mix",
    "stream_source",
    "within",
]

BLOCK_BITS = 8
"""A sample ends a block when the low ``BLOCK_BITS`` bits of its mix are zero (mean block
length 2**8 = 256 samples)."""
_MASK = np.uint64((1 << BLOCK_BITS) - 1)
_U = np.uint64


def sample_mix(x: NDArray) -> NDArray:
    """A 64-bit mix of each row of ``x`` (n, 8) float64 (its bytes exact): per column an
    xor-multiply step, then the splitmix64 finaliser."""
    u = np.ascontiguousarray(x, np.float64).view(np.uint64)
    h = np.full(len(u), _U(0x9E3779B97F4A7C15), np.uint64)
    for c in range(u.shape[1]):
        h ^= u[:, c]
        h *= _U(0x100000001B3)
        h ^= h >> _U(29)
    h ^= h >> _U(30)
    h *= _U(0xBF58476D1CE4E5B9)
    h ^= h >> _U(27)
    h *= _U(0x94D049BB133111EB)
    h ^= h >> _U(31)
    return h


def _b64(h: NDArray) -> str:
    return base64.b64encode(np.ascontiguousarray(h, "<u8").tobytes()).decode()


def _unb64(s: str) -> NDArray:
    return np.frombuffer(base64.b64decode(s), "<u8").astype(np.uint64)


@dataclass
class _Run:
    """One run of a stream (module docstring); ``head_closed``: the head ends at a
    block-ending sample."""

    d: str
    n: int
    head: NDArray
    head_closed: bool
    blocks: list[tuple[str, int]]
    tail: NDArray
    before_tail: int = -1  # the mix of the block-ending sample before the tail

    def to_json(self) -> dict[str, Any]:
        return {"d": self.d, "n": self.n, "head": _b64(self.head), "hc": self.head_closed,
                "blocks": [list(b) for b in self.blocks], "tail": _b64(self.tail),
                "bt": str(self.before_tail)}  # fmt: skip

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> _Run:
        return cls(str(d["d"]), int(d["n"]), _unb64(d["head"]), bool(d["hc"]),
                   [(str(a), int(b)) for a, b in d["blocks"]], _unb64(d["tail"]),
                   int(d.get("bt", -1)))  # fmt: skip


@dataclass
class StreamId:
    """A unit's stream: its runs (module docstring) and sample count."""

    runs: list[_Run] = field(default_factory=list)

    @property
    def samples(self) -> int:
        return sum(r.n for r in self.runs)

    def key(self) -> tuple:
        """Equal for equal streams (every run's digest and count)."""
        return tuple((r.d, r.n) for r in self.runs)

    def dumps(self) -> str:
        """JSON text for the store (``log_sources.identity``)."""
        return json.dumps([r.to_json() for r in self.runs], separators=(",", ":"))

    @classmethod
    def loads(cls, text: str) -> StreamId:
        return cls([_Run.from_json(d) for d in json.loads(text)])


def stream_source(unit: str, sid: StreamId) -> str:
    """The store's source of a log's unit: ``log:`` and 32 hex digits of a digest over the
    unit's name and its runs' digests (every sample, nothing of the file's name)."""
    h = hashlib.blake2b(unit.encode(), digest_size=16)
    for d, n in sid.key():
        h.update(f"{d}:{n};".encode())
    return f"log:{h.hexdigest()}"


@dataclass
class Relation:
    """How a new stream stands to a stored one: ``equal``; ``inside`` (the stored one holds
    every sample of the new one; ``exact``: its edges compared sample by sample);
    ``holds`` (the new one holds every sample of the stored one, checked exactly while it
    was read); ``shared``: samples of closed blocks the two have in common."""

    equal: bool = False
    inside: bool = False
    exact: bool = True
    holds: bool = False
    shared: int = 0


class Relations(dict):
    """``{source: Relation}`` of a new stream against the stored ones it was read with;
    called with a source, its relation (None: not compared)."""

    def __call__(self, source: str) -> Relation | None:
        return self.get(source)


class StreamDigest:
    """Builds a unit's ``StreamId`` from its accepted samples (``add``, ``cut`` at a corrupt
    chunk, ``finish``) and, while it reads, finds which ``stored`` streams (``{source:
    StreamId}``) lie within it (``holds``)."""

    def __init__(self, stored: Mapping[str, StreamId] | None = None) -> None:
        self.runs: list[_Run] = []
        self._stored = dict(stored or {})
        # stored runs by the mix of their head's last sample / of the sample before their tail
        self._heads: dict[int, list[tuple[str, int]]] = {}
        self._tails: dict[int, list[tuple[str, int]]] = {}
        self._wholes: list[tuple[str, int]] = []
        for src, sid in self._stored.items():
            for i, r in enumerate(sid.runs):
                if not r.head_closed:
                    self._wholes.append((src, i))
                    continue
                self._heads.setdefault(int(r.head[-1]), []).append((src, i))
                if len(r.tail):
                    self._tails.setdefault(r.before_tail, []).append((src, i))
        self._found: set[tuple[str, int]] = set()  # stored runs found within this stream
        # per stored run: the global index of the new block its head ended, when matched
        self._head_at: dict[tuple[str, int], list[int]] = {}
        self._tail_at: dict[tuple[str, int], set[int]] = {}
        self._nblocks: list[tuple[str, int]] = []  # every block of the new stream, in order
        self._after_boundary: int | None = None  # mix of the block-ending sample before
        self._begin_run()

    @property
    def stored(self) -> Mapping[str, StreamId]:
        """The stored streams this digest compares with."""
        return self._stored

    # -- building --------------------------------------------------------------------------
    def _begin_run(self) -> None:
        self._rh = hashlib.blake2b(digest_size=16)
        self._rn = 0
        self._head: NDArray | None = None
        self._blocks: list[tuple[str, int]] = []
        self._bh = hashlib.blake2b(digest_size=16)
        self._bbuf: list[NDArray] = []
        self._bn = 0
        self._after_boundary = None
        self._last_end = -1
        self._open_tail = np.empty(0, np.uint64)

    def add(self, x: NDArray) -> None:
        """Accepted samples (n, 8): time and the seven channels, in stream order."""
        x = np.ascontiguousarray(x, np.float64)
        if not len(x):
            return
        h = sample_mix(x)
        raw = x.tobytes()
        self._rn += len(x)
        ends = np.flatnonzero((h & _MASK) == 0)
        a = 0
        w = x.shape[1] * 8
        for e in ends.tolist():
            self._bh.update(raw[a * w : (e + 1) * w])
            self._bbuf.append(h[a : e + 1])
            self._bn += e + 1 - a
            self._close_block(True)
            a = e + 1
        if a < len(x):
            self._bh.update(raw[a * w :])
            self._bbuf.append(h[a:])
            self._bn += len(x) - a

    def _close_block(self, at_boundary: bool) -> None:
        hb = np.concatenate(self._bbuf) if self._bbuf else np.empty(0, np.uint64)
        dig = (self._bh.hexdigest(), self._bn)
        self._rh.update(f"{dig[0]}:{dig[1]};".encode())  # the run's digest: its blocks' chain
        idx = len(self._nblocks)
        self._nblocks.append(dig)
        self._match(hb, idx, at_boundary)
        if self._head is None and at_boundary:
            self._head = hb
        elif at_boundary:
            self._blocks.append(dig)
        else:
            self._open_tail = hb
        self._after_boundary = int(hb[-1]) if at_boundary and len(hb) else None
        if at_boundary:
            self._last_end = int(hb[-1])
        self._bh = hashlib.blake2b(digest_size=16)
        self._bbuf = []
        self._bn = 0

    def _match(self, hb: NDArray, idx: int, at_boundary: bool) -> None:
        """Stored runs' heads that end this block, tails that start it, wholes inside it."""
        if at_boundary and len(hb):
            for key in self._heads.get(int(hb[-1]), ()):
                head = self._stored[key[0]].runs[key[1]].head
                if len(head) <= len(hb) and np.array_equal(hb[len(hb) - len(head) :], head):
                    self._head_at.setdefault(key, []).append(idx)
        if self._after_boundary is not None:
            for key in self._tails.get(self._after_boundary, ()):
                t = self._stored[key[0]].runs[key[1]].tail
                if len(t) <= len(hb) and np.array_equal(hb[: len(t)], t):
                    self._tail_at.setdefault(key, set()).add(idx)
        for key in self._wholes:
            whole = self._stored[key[0]].runs[key[1]].head
            if _contains(hb, whole):
                self._found.add(key)

    def cut(self) -> None:
        """A gap in the stream (a corrupt chunk skipped): the run so far ends here."""
        self._end_run()
        self._nblocks.append(("", -1))  # no run continues across the gap
        self._begin_run()

    def _end_run(self) -> None:
        if self._rn == 0:
            return
        self._open_tail = np.empty(0, np.uint64)
        if self._bn:
            self._close_block(False)
        if self._head is None:  # no block-ending sample: the whole run is its head
            self.runs.append(_Run(self._rh.hexdigest(), self._rn, self._open_tail, False, [],
                                  np.empty(0, np.uint64)))  # fmt: skip
            return
        self.runs.append(_Run(self._rh.hexdigest(), self._rn, self._head, True,
                              self._blocks, self._open_tail, self._last_end))  # fmt: skip

    def finish(self) -> StreamId:
        """The stream's identity (call once, after the last ``add``)."""
        self._end_run()
        self._rn = 0
        return StreamId(self.runs)

    # -- relations -------------------------------------------------------------------------
    def holds(self, source: str) -> bool:
        """Every run of stored ``source`` lies within this stream (after ``finish``)."""
        sid = self._stored[source]
        return bool(sid.runs) and all(self._run_within(source, i, r)
                                      for i, r in enumerate(sid.runs))  # fmt: skip

    def _run_within(self, src: str, i: int, r: _Run) -> bool:
        if not r.head_closed:
            return (src, i) in self._found
        k = len(r.blocks)
        for at in self._head_at.get((src, i), ()):
            if self._nblocks[at + 1 : at + 1 + k] != [tuple(b) for b in r.blocks]:
                continue
            nxt = at + 1 + k
            if not len(r.tail) or nxt in self._tail_at.get((src, i), ()):
                return True
        return False

    def relate(self, new: StreamId) -> Relations:
        """``source -> relation(new, source)`` for the stored streams this digest compared
        with while it read (None for any other source), made now so that it travels with
        the log's units (a worker's result is pickled to the client that writes the store)."""
        return Relations({src: self.relation(new, src) for src in self._stored})

    def relation(self, new: StreamId, source: str) -> Relation:
        """``new`` (this digest's ``finish()``) against stored ``source``."""
        old = self._stored[source]
        rel = Relation()
        if new.key() == old.key():
            rel.equal = rel.inside = rel.holds = True
            rel.shared = new.samples
            return rel
        rel.holds = self.holds(source)
        mine = {b for r in new.runs for b in r.blocks}
        rel.shared = sum(c for r in old.runs for b in r.blocks if b in mine for c in [b[1]])
        ins = [within(r, old) for r in new.runs]
        rel.inside = bool(ins) and all(x is not None for x in ins)
        rel.exact = rel.inside and all(bool(x) for x in ins)
        return rel


def _contains(hay: NDArray, needle: NDArray) -> bool:
    """``needle`` occurs in ``hay`` as a contiguous run."""
    n = len(needle)
    if n == 0 or n > len(hay):
        return n == 0
    for s in np.flatnonzero(hay[: len(hay) - n + 1] == needle[0]).tolist():
        if np.array_equal(hay[s : s + n], needle):
            return True
    return False


def within(r: _Run, old: StreamId) -> bool | None:
    """Whether run ``r`` of a new stream lies within stored ``old``: None if not; True if
    every sample was compared (its edge blocks fall on ``old``'s heads and tails), False if
    its closed blocks lie in ``old`` and an edge block fits by count only."""
    for o in old.runs:
        if not r.head_closed:  # no block-ending sample: only a stored head or tail shows it
            if _contains(o.head, r.head) or _contains(o.tail, r.head):
                return True
            continue
        if not o.head_closed:
            continue
        # the stored run's blocks: its head, its closed blocks, its tail (if any)
        seq: list[tuple] = [("h", len(o.head))] + [tuple(b) for b in o.blocks]
        seq += [("t", len(o.tail))] if len(o.tail) else []
        mine = [tuple(b) for b in r.blocks]
        k = len(mine)
        last_closed = len(o.blocks)  # index in seq of the last block that ends at a boundary
        for j in range(1, last_closed + 2):  # r's head ends seq[j - 1]'s last sample
            if seq[j : j + k] != mine or j + k - 1 > last_closed:
                continue
            before = seq[j - 1]
            exact = True
            if before[0] == "h":
                if len(r.head) > len(o.head) or not np.array_equal(
                    o.head[len(o.head) - len(r.head) :], r.head
                ):
                    continue
            elif len(r.head) > before[1]:
                continue
            else:
                exact = False
            if len(r.tail):
                after = seq[j + k] if j + k < len(seq) else None
                if after is None:
                    continue
                if after[0] == "t":
                    if len(r.tail) > len(o.tail) or not np.array_equal(
                        o.tail[: len(r.tail)], r.tail
                    ):
                        continue
                elif len(r.tail) >= after[1]:
                    continue
                else:
                    exact = False
            return exact
    return None
