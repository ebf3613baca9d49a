"""Logs written before decision 0011 (JSON rows) stay readable, replayable and ingestible.

``tests/data/json_rows_log.mcap`` was written by the code before the protobuf rows: the
meas of two actuators (times from 1.7e9 s, 120 samples each, the second without a current
sensor) logged as the daemon logs them, then replayed with ``--out`` (meas, est, residual,
health as the daemon writes them; every message JSON).
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from service.log import read_blocks, read_log
from service.replay import replay
from service.store import open_store

FIXTURE = Path(__file__).parent / "data" / "json_rows_log.mcap"
ACTS = ("AC001/elevator_L", "AC001/aileron_R")
LEAVES = ("meas", "est", "residual", "health")


def _encodings(path: Path) -> dict[str, str]:
    with open(path, "rb") as f:
        s = make_reader(f).get_summary()
    return {c.topic: c.message_encoding for c in s.channels.values()}


def _rows(path: Path) -> dict[str, tuple[np.ndarray, tuple[str, ...], np.ndarray]]:
    """topic -> (log times [s], field names, values) of every row topic, via read_blocks."""
    out: dict[str, list] = {}
    for b in read_blocks(path):
        out.setdefault(b.topic, []).append(b)
    res = {}
    for topic, bs in out.items():
        assert len({b.names for b in bs}) == 1, topic
        res[topic] = (
            np.concatenate([b.t for b in bs]),
            bs[0].names,
            np.concatenate([b.values for b in bs]),
        )
    return res


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Bit for bit, NaN equal to NaN."""
    na, nb = np.isnan(a), np.isnan(b)
    return bool(
        np.array_equal(na, nb)
        and np.array_equal(
            np.where(na, 0.0, a).view(np.uint64), np.where(nb, 0.0, b).view(np.uint64)
        )
    )


def test_the_fixture_is_a_json_log():
    enc = _encodings(FIXTURE)
    assert set(enc.values()) == {"json"}
    assert {t.rsplit("/", 1)[-1] for t in enc} == set(LEAVES)


def test_json_log_reads_by_blocks_as_by_messages():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a complete file: no truncation warning
        msgs = list(read_log(FIXTURE))
        rows = _rows(FIXTURE)
    assert len(msgs) == 2 * 4 * 120
    for topic, (t, names, vals) in rows.items():
        ref = [(x, m) for tp, x, m in msgs if tp == topic]
        assert t.tolist() == [x for x, _ in ref]
        exp = np.array([[np.nan if m[k] is None else float(m[k]) for k in names] for _, m in ref])
        assert _same(vals, exp), topic


def test_json_log_replays_and_converts_bit_for_bit(tmp_path):
    """The replay of the old log writes its measurements as protobuf rows with the same
    numbers, bit for bit, and its outputs equal those of a replay of that conversion (the
    fixture's own est rows are the monitor of their time: a model change moves them)."""
    out, again = tmp_path / "replayed.mcap", tmp_path / "again.mcap"
    s = replay(FIXTURE, out=out)
    assert s.samples == 240 and s.outputs == 240 and not s.truncated
    assert {v for t, v in _encodings(out).items() if t.rsplit("/", 1)[-1] in LEAVES} == {"protobuf"}
    old, new = _rows(FIXTURE), _rows(out)
    assert set(old) == set(new)
    for topic in old:
        to, no, vo = old[topic]
        tn, nn, vn = new[topic]
        assert no == nn and np.array_equal(to, tn), topic
        if topic.endswith("/meas"):
            assert _same(vo, vn), topic
    s2 = replay(out, out=again)
    assert s2.final == s.final
    rep = _rows(again)
    for topic in new:
        assert _same(new[topic][2], rep[topic][2]), topic


def test_json_log_ingests_into_a_store_as_its_protobuf_conversion(tmp_path):
    """``replay --store`` of the old log stores the periods its protobuf conversion stores."""
    conv = tmp_path / "conv.mcap"
    replay(FIXTURE, out=conv)
    got = {}
    for name, log in (("json", FIXTURE), ("protobuf", conv)):
        store = tmp_path / f"{name}.sqlite"
        s = replay(log, store=str(store))
        assert s.samples == 240
        with open_store(str(store)) as st:
            got[name] = {a: [dataclasses.asdict(p) for p in st.periods(a)] for a in ACTS}
    assert all(got["json"][a] for a in ACTS)
    for a in ACTS:
        for pj, pp in zip(got["json"][a], got["protobuf"][a], strict=True):
            pj.pop("source"), pp.pop("source")  # the log file's id
            assert pj.keys() == pp.keys() and pj["samples"] > 0
            assert all(_same(np.array([pj[k]], float), np.array([pp[k]], float))
                       if isinstance(pj[k], float) else pj[k] == pp[k] for k in pj), a  # fmt: skip
