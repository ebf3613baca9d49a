"""The log for outside readers (issue 54, decision 0043): events are ``servowatch.Event``
protobuf rows like the other topics, so the stock protobuf decoder reads every topic; each
schema carries its fields' units as field comments, each channel as ``units`` metadata; old
logs with JSON events keep reading."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from service.log import McapLogger, read_blocks, read_log
from service.log.events import decode_event, encode_event, event_schema
from service.log.proclog import MEAS_LOG_FIELDS

ROOT = Path(__file__).resolve().parents[1]
LEAK = {"t": 1796378000.5, "kind": "leak", "state": "raised", "value": 3.93}
SILENT = {"t": 1796378001.0, "kind": "silent", "value": 2.5, "wall": 1796378003.25}


def _write(path: Path) -> None:
    with McapLogger(path, background_flush=False) as lg:
        vals = np.column_stack([np.full((4, 7), 1e5), np.arange(4), np.arange(4) * 1e-3])
        lg.log_block("/fleet/AC1/x/meas", np.arange(4) * 1e-3, MEAS_LOG_FIELDS, vals,
                     int_fields=("seq",))  # fmt: skip
        lg.log_event("/fleet/AC1/x/events", LEAK["t"], LEAK)
        lg.log_event("/fleet/AC1/x/service", SILENT["t"], SILENT)
        lg.log_event("/fleet/AC1/x/service", 5.0, {"t": 5.0, "kind": "restart", "value": "seq 7"})


def test_the_stock_protobuf_decoder_reads_every_topic(tmp_path):
    p = tmp_path / "a.mcap"
    _write(p)
    seen = []
    with open(p, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, _message, row in reader.iter_decoded_messages():
            assert schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
            seen.append((channel.topic, row))
    topics = [t for t, _ in seen]
    assert topics.count("/fleet/AC1/x/meas") == 4 and topics.count("/fleet/AC1/x/service") == 2
    ev = next(r for t, r in seen if t.endswith("/events"))
    assert (ev.t, ev.kind, ev.state, ev.value) == (LEAK["t"], "leak", "raised", 3.93)
    assert math.isnan(ev.wall)
    restart = next(r for t, r in seen if t.endswith("/service") and r.kind == "restart")
    assert json.loads(restart.detail) == {"value": "seq 7"} and math.isnan(restart.value)


def test_servowatch_reads_events_back_as_the_json_events_were(tmp_path):
    p = tmp_path / "a.mcap"
    _write(p)
    evs = [m for t, _, m in read_log(p) if not t.endswith("/meas")]
    assert evs[0] == {**LEAK, "wall": None, "state": "raised"}
    assert evs[1] == {**SILENT, "state": None}
    assert evs[2] == {"t": 5.0, "kind": "restart", "state": None, "value": "seq 7", "wall": None}
    blocks = {b.topic: b for b in read_blocks(p)}
    b = blocks["/fleet/AC1/x/events"]
    assert b.names[:1] == ("t",) and b.values[0, 0] == LEAK["t"] and b.values[0, 3] == 3.93


def test_units_are_field_comments_and_channel_metadata(tmp_path):
    p = tmp_path / "a.mcap"
    _write(p)
    with open(p, "rb") as f:
        summary = make_reader(f).get_summary()
    by_topic = {c.topic: c for c in summary.channels.values()}
    meas = by_topic["/fleet/AC1/x/meas"]
    units = json.loads(meas.metadata["units"])
    assert (
        units["p1"].startswith("Pa") and units["t"].startswith("s") and units["i"].startswith("A")
    )
    fds = descriptor_pb2.FileDescriptorSet.FromString(summary.schemas[meas.schema_id].data)
    comments = {
        tuple(loc.path): loc.leading_comments for loc in fds.file[0].source_code_info.location
    }
    fields = fds.file[0].message_type[0].field
    k = [f.name for f in fields].index("x_j")
    assert comments[(4, 0, 2, k)].strip() == "[m (jack position)]"
    ev = by_topic["/fleet/AC1/x/events"]
    assert "value" in json.loads(ev.metadata["units"])
    efds = descriptor_pb2.FileDescriptorSet.FromString(summary.schemas[ev.schema_id].data)
    assert efds.file[0].message_type[0].name == "Event"
    assert len(efds.file[0].source_code_info.location) == 6
    assert summary.schemas[ev.schema_id].data == event_schema()


def test_an_old_log_with_json_events_keeps_reading():
    old = ROOT / "tests" / "data" / "json_rows_log.mcap"
    msgs = list(read_log(old))
    assert msgs and all(isinstance(m, dict) for _, _, m in msgs)


@pytest.mark.parametrize(
    "d",
    [LEAK, SILENT, {"t": 1.0, "kind": "x", "value": None, "extra": [1, 2]}, {"kind": "k"}],
)
def test_encode_decode_round_trip(d):
    back = decode_event(encode_event(d))
    for k, v in d.items():
        assert back[k] == v or (v is None and back.get(k) is None)


def _snippets() -> list[str]:
    text = (ROOT / "docs" / "messages.md").read_text()
    i = text.index("### Reading a log without servowatch")
    return text[i:].split("```python\n")[1:4]


def test_the_docs_snippets_read_every_topic_and_a_growing_log(tmp_path, monkeypatch, capsys):
    """docs/messages.md's snippets, run as they are on this project's logs."""
    monkeypatch.chdir(tmp_path)
    _, all_topics, growing = (s.split("```")[0] for s in _snippets())
    lg = McapLogger(tmp_path / "live.mcap", background_flush=False)
    lg.log_rows(["/fleet/AC001/elevator_L/health"], [1], np.array([1.0]),
                ["leak_ratio", "supply_ratio"], np.array([[3.9, 1.0]]))  # fmt: skip
    lg.log_event("/fleet/AC001/elevator_L/events", LEAK["t"], LEAK)
    lg.flush()
    growing_name = "servowatch-ground1-0-20261204T095217Z-0000-20261204T095219Z.mcap"
    (tmp_path / growing_name).write_bytes((tmp_path / "live.mcap").read_bytes())  # unfinished
    exec(compile(growing, "growing", "exec"), {})
    out = capsys.readouterr().out.splitlines()
    assert out == [
        "/fleet/AC001/elevator_L/health 1.0",
        f"/fleet/AC001/elevator_L/events {LEAK['t']}",
    ]
    from mcap.exceptions import McapError

    f = open(tmp_path / growing_name, "rb")  # noqa: SIM115
    with f, pytest.raises(McapError):  # what the issue met: make_reader on a growing file
        list(make_reader(f).iter_messages())
    lg.close()
    exec(compile(all_topics, "all_topics", "exec"), {})
    out = capsys.readouterr().out.splitlines()
    assert "3.9 1 (C_Lk over the baseline's)" in out
    assert f"{LEAK['t']} leak raised 3.93" in out


def test_layout_writes_the_foxglove_layout_of_any_unit(tmp_path, monkeypatch, capsys):
    """``servowatch layout --unit AC/ACT``: the shipped layout with the unit's topics (the
    shipped file is AC001/elevator_L's, made by the same code)."""
    from service.cli import main
    from service.edge.foxglove_layout import layout_json

    shipped = (ROOT / "deploy" / "foxglove" / "servowatch-layout.json").read_text()
    assert layout_json("AC001", "elevator_L") == shipped
    monkeypatch.chdir(tmp_path)
    assert main(["layout", "--unit", "AC002/aileron_R"]) == 0
    text = (tmp_path / "servowatch-layout-AC002-aileron_R.json").read_text()
    assert text == shipped.replace("AC001/elevator_L", "AC002/aileron_R")
    assert "/fleet/AC002/aileron_R/events" in text and "AC001" not in text
    assert main(["layout", "--unit", "AC002"]) == 2
    assert "--unit: expected AIRCRAFT/ACTUATOR" in capsys.readouterr().err
