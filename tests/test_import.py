"""``servowatch import`` (issue 52, docs/import.md): files written by each format's own library
in a rig's names and units become ordinary logs with the values in SI; bad inputs are one
line naming the file and the field, exit 2, nothing left behind; the same input gives the
same log bytes and a second import writes nothing; several rates meet on one grid
(anti-aliased); gaps and times that repeat or step back are counted by the intake's rules."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import rig_files as rf  # noqa: E402

from service.cli import main  # noqa: E402
from service.importer import read_import_record  # noqa: E402
from service.log import read_blocks  # noqa: E402

WRITERS = {
    "tdms": (rf.write_tdms, ".tdms", "Rig/", ""),
    "mdf": (rf.write_mdf4, ".mf4", "", ""),
    "parquet": (rf.write_parquet, ".parquet", "", '[time]\ncolumn = "Time"\nunit = "s"'),
    "csv": (rf.write_csv, ".csv", "", '[time]\ncolumn = "Time_ms"\nunit = "ms"'),
}


@pytest.fixture(scope="module")
def healthy() -> dict[str, np.ndarray]:
    return rf.run("healthy", seconds=1.5)


def _write(tmp: Path, fmt: str, meas, name: str = "run") -> tuple[Path, Path]:
    writer, ext, prefix, time = WRITERS[fmt]
    f = writer(tmp / f"{name}{ext}", meas)
    mp = tmp / f"{fmt}.toml"
    mp.write_text(rf.map_text(fmt, prefix, time))
    return f, mp


def _log(path: Path) -> tuple[str, tuple, np.ndarray]:
    blocks = list(read_blocks(path))
    assert {b.topic for b in blocks} == {"/fleet/RIG1/rudder/meas"}
    return blocks[0].topic, blocks[0].names, np.vstack([b.values for b in blocks])


def _leftovers(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir() if p.name.startswith("."))


@pytest.mark.parametrize("fmt", sorted(WRITERS))
def test_each_format_gives_the_values_in_si(tmp_path, healthy, fmt, capsys):
    f, mp = _write(tmp_path, fmt, healthy)
    out = tmp_path / "run.mcap"
    start = ["--start-unix", "1772352000"] if fmt in ("parquet", "csv") else []
    assert main(["import", str(f), "--map", str(mp), "--out", str(out), *start]) == 0
    _, names, v = _log(out)
    assert names == ("x_cmd", "i", "x_s", "x_j", "p1", "p2", "seq", "t")
    n = len(healthy["t"])
    assert v.shape == (n, 8)
    assert np.array_equal(v[:, 6], np.arange(n))  # seq: the grid index
    # the time axis: the file's start (TDMS wf_start_time, MDF header) or --start-unix
    np.testing.assert_allclose(v[:, 7], rf.START.timestamp() + np.arange(n) / 1000.0, rtol=0,
                               atol=1e-6)  # fmt: skip
    for c, ch in enumerate(names[:6]):
        np.testing.assert_allclose(v[:, c], healthy[ch], rtol=1e-12, atol=1e-18)
    md = read_import_record(out)
    assert md["file"] == f.name and len(md["sha256"]) == 64 and "RamPos" in md["map"]
    assert md["format"] == fmt


def test_same_input_same_bytes_and_a_second_import_writes_nothing(tmp_path, healthy, capsys):
    f, mp = _write(tmp_path, "tdms", healthy)
    a, b = tmp_path / "a.mcap", tmp_path / "b" / "a.mcap"
    assert main(["import", str(f), "--map", str(mp), "--out", str(a)]) == 0
    assert main(["import", str(f), "--map", str(mp), "--out", str(b.parent)]) == 0
    b = b.with_name("run.mcap")
    assert a.read_bytes() == b.read_bytes()
    st = a.stat().st_mtime_ns
    capsys.readouterr()
    assert main(["import", str(f), "--map", str(mp), "--out", str(a)]) == 0
    assert "unchanged" in capsys.readouterr().out
    assert a.stat().st_mtime_ns == st
    # another flight is another import: refused, the log kept
    assert main(["import", str(f), "--map", str(mp), "--out", str(a), "--flight", "4"]) == 2
    assert "is not this file's import" in capsys.readouterr().err
    assert a.stat().st_mtime_ns == st


def test_flight_record_and_replay_identity(tmp_path, healthy, capsys):
    from service.log.flightrec import flight_records

    f, mp = _write(tmp_path, "mdf", healthy)
    out = tmp_path / "run.mcap"
    assert main(["import", str(f), "--map", str(mp), "--out", str(out), "--flight", "7"]) == 0
    (rec,) = flight_records(out)
    assert (rec.name, rec.flight, rec.start_unix) == ("RIG1/rudder", 7, rf.START.timestamp())


def _cut(p: Path, frac: float) -> Path:
    data = p.read_bytes()
    p.write_bytes(data[: int(len(data) * frac)])
    return p


BAD = {
    # name: (format, edit(tmp, file, map) -> args, field in the message, more text)
    "missing column": ("csv", lambda f, mp: mp.write_text(mp.read_text().replace("RamPos", "RamPosn")),
                       "channels.x_j.column", "the file has 'Time_ms', 'PosDemand'"),
    "wrong dimension": ("tdms", lambda f, mp: mp.write_text(mp.read_text().replace('"bar"', '"mm"', 1)),
                        "channels.p1", "not [pressure]"),
    "unknown unit": ("tdms", lambda f, mp: mp.write_text(mp.read_text().replace('"bar"', '"bart"', 1)),
                     "channels.p1", "not a unit"),
    "map typo": ("parquet", lambda f, mp: mp.write_text(mp.read_text().replace("column = \"Time\"", "colum = \"Time\"")),
                 "time.colum", "unknown field"),
    "another format": ("csv", lambda f, mp: mp.write_text(mp.read_text().replace('"csv"', '"tdms"')),
                       "format", "the map's format says tdms, the file is csv"),
    "section typo": ("tdms", lambda f, mp: mp.write_text(mp.read_text().replace("[channels]", "[channel]")),
                     "channel", "unknown field (a typo?)"),
    "binary as csv": ("csv", lambda f, mp: f.write_bytes(bytes(range(256)) * 4),
                      "format", "says csv, the file is unknown binary"),
    "empty file": ("csv", lambda f, mp: f.write_bytes(b""), "file", "empty file"),
    "truncated tdms": ("tdms", lambda f, mp: _cut(f, 0.6), "file", "truncated"),
    "truncated mdf": ("mdf", lambda f, mp: _cut(f, 0.5), "file", "MDF"),
    "truncated parquet": ("parquet", lambda f, mp: _cut(f, 0.7), "file", "Parquet"),
    "truncated csv": ("csv", lambda f, mp: _cut(f, 0.5), "file", "CSV parse error"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, healthy, case, capsys):
    fmt, edit, field, text = BAD[case]
    f, mp = _write(tmp_path, fmt, healthy)
    edit(f, mp)
    out = tmp_path / "out" / "new" / "run.mcap"  # its folders made by the import
    out.parent.parent.mkdir()
    capsys.readouterr()
    code = main(["import", str(f), "--map", str(mp), "--out", str(out), "--start-unix", "0"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1, err
    assert field in err and text in err, err
    assert str(f) in err or str(mp) in err, err
    assert list(out.parent.parent.iterdir()) == []  # not even the folder it would have made


def test_an_all_nan_channel_is_refused(tmp_path, healthy, capsys):
    meas = dict(healthy, p2=np.full_like(healthy["p2"], np.nan))
    f, mp = _write(tmp_path, "parquet", meas)
    out = tmp_path / "o" / "run.mcap"
    out.parent.mkdir()
    assert main(["import", str(f), "--map", str(mp), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{f}: channels.p2: column 'P_B' holds no finite value" in err
    assert list(out.parent.iterdir()) == [] and _leftovers(tmp_path) == []


def test_gaps_and_times_that_repeat_or_step_back_are_counted(tmp_path, healthy, capsys):
    import pyarrow as pa
    import pyarrow.parquet as pq

    n = len(healthy["t"])
    keep = np.r_[0:500, 700:n]  # a 0.2 s gap
    t = healthy["t"][keep].copy()
    t[100] = t[99]  # a repeated time
    t[300] = t[290]  # a time that steps back
    cols = {"Time": t, **{k: v[keep] for k, v in rf.rig_columns(healthy).items()}}
    f = tmp_path / "gappy.parquet"
    pq.write_table(pa.table(cols), f)
    mp = tmp_path / "m.toml"
    mp.write_text(rf.map_text("parquet", "", '[time]\ncolumn = "Time"'))
    out = tmp_path / "gappy.mcap"
    assert main(["import", str(f), "--map", str(mp), "--out", str(out), "--json"]) == 0
    import json

    (res,) = json.loads(capsys.readouterr().out)["imports"]
    c = res["counts"]
    # the 0.2 s gap, and the one-sample holes the two refused samples leave
    assert c["gaps"] == 3 and c["intake"] == {"duplicate": 1, "clock": 1, "refused": 2}
    assert c["copied"] == len(keep) - 2 == res["samples"]
    _, _, v = _log(out)
    seq = v[:, 6]
    jumps = np.flatnonzero(np.diff(seq) > 1)  # each gap a seq jump, as live
    assert seq[jumps + 1].tolist() == [101, 301, 700] and seq.max() == n - 1


def test_several_rates_meet_on_one_grid_anti_aliased(tmp_path, healthy, capsys):
    """MDF with the rig's 1 kHz group, a 5 kHz supply pressure holding a 2.2 kHz tone (which
    would alias to 200 Hz at 1 kHz without the filter) and a 100 Hz supply in another unit."""
    t5 = np.arange(int(1.5 * 5000)) / 5000.0
    p_sr5 = 200.0 + 2.0 * np.sin(2 * np.pi * 3.0 * t5) + 5.0 * np.sin(2 * np.pi * 2200.0 * t5)
    t01 = np.arange(150) / 100.0
    slow = {
        "P_Supply": (t5, p_sr5, "bar"),
        "DemandSlow": (t01, 2.0 * np.sin(2 * np.pi * t01), "mm"),
    }
    f = rf.write_mdf4(tmp_path / "multi.mf4", healthy, slow)
    text = rf.map_text("mdf").replace('column = "PosDemand"', 'column = "DemandSlow"')
    mp = tmp_path / "m.toml"
    mp.write_text(text + 'p_sr = { column = "P_Supply", unit = "bar" }\n')
    out = tmp_path / "multi.mcap"
    assert main(["import", str(f), "--map", str(mp), "--out", str(out), "--json"]) == 0
    import json

    c = json.loads(capsys.readouterr().out)["imports"][0]["counts"]
    assert c["downsampled"] == len(t5) and c["copied"] == len(healthy["t"])
    assert c["interpolated"] == 1491  # 0 .. 1.49 s of the 100 Hz channel at 1 kHz
    _, names, v = _log(out)
    t = v[:, names.index("t")] - rf.START.timestamp()
    p_sr = v[:, names.index("p_sr")]
    ok = np.isfinite(p_sr) & (t > 0.05) & (t < 1.45)
    resid = p_sr[ok] / 1e5 - (200.0 + 2.0 * np.sin(2 * np.pi * 3.0 * t[ok]))
    assert np.max(np.abs(resid)) < 0.05  # the 5 bar tone is gone, not folded to 200 Hz
    x_cmd = v[:, names.index("x_cmd")]
    ok = np.isfinite(x_cmd)
    np.testing.assert_allclose(x_cmd[ok], 2e-3 * np.sin(2 * np.pi * t[ok]), atol=2e-3 * 0.002)
    assert np.isnan(x_cmd[t > 1.4901]).all()  # no value past the slow channel's last sample


def test_the_polyphase_blocks_equal_one_call(monkeypatch):
    from scipy.signal import resample_poly

    from service.importer import timebase

    monkeypatch.setattr(timebase, "_BLOCK", 1000)
    rng = np.random.default_rng(0)
    x = rng.standard_normal((12345, 2))
    rs = timebase.SeriesResampler(0.0, 1000.0, 1 / 3000.0)  # 3 kHz -> 1 kHz
    t = np.arange(len(x)) / 3000.0
    parts = [p for a in range(0, len(x), 777) for p in rs.push(t[a:a + 777], x[a:a + 777])]  # fmt: skip
    parts += list(rs.finish())
    k = np.concatenate([p[0] for p in parts])
    y = np.vstack([p[1] for p in parts])
    whole = resample_poly(x, 1, 3, axis=0, padtype="edge")
    assert np.array_equal(k, np.arange(len(whole)))
    np.testing.assert_allclose(y, whole, rtol=0, atol=1e-12)


def test_a_parquet_file_another_tool_wrote(tmp_path, capsys):
    """pyarrow's own test file written by parquet-cpp 0.7.1 (2017): ten rows of a table."""
    import pyarrow

    f = Path(pyarrow.__file__).parent / "tests" / "data" / "parquet" / "v0.7.1.parquet"
    if not f.exists():
        pytest.skip("this pyarrow wheel ships no test data")
    mp = tmp_path / "m.toml"
    mp.write_text('[time]\ncolumn = "__index_level_0__"\nrate_hz = 1.0\n[actuator]\n'
                  'aircraft = "AC1"\nname = "gem"\n[channels]\n'
                  'x_j = { column = "depth", unit = "mm" }\n')  # fmt: skip
    out = tmp_path / "gem.mcap"
    assert main(["import", str(f), "--map", str(mp), "--out", str(out)]) == 0
    (b,) = list(read_blocks(out))
    assert b.names == ("x_j", "seq", "t") and len(b.t) == 10
    assert math.isclose(b.values[0, 0], 61.5e-3) and b.values[-1, 2] == 9.0
    bad = mp.read_text().replace('"depth"', '"dept"')
    mp.write_text(bad)
    assert main(["import", str(f), "--map", str(mp), "--out", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err
    assert "channels.x_j.column: no column 'dept'; the file has 'carat', 'cut', 'color'" in err


def test_absolute_timestamps_in_a_csv(tmp_path, healthy, capsys):
    import datetime as dt

    import pyarrow as pa
    import pyarrow.csv as pcsv

    n = 500
    stamps = [(rf.START + dt.timedelta(milliseconds=k)).isoformat() for k in range(n)]
    cols = {"Stamp": stamps, **{k: v[:n] for k, v in rf.rig_columns(healthy).items()}}
    f = tmp_path / "abs.csv"
    pcsv.write_csv(pa.table(cols), f)
    mp = tmp_path / "m.toml"
    mp.write_text(rf.map_text("csv", "", '[time]\ncolumn = "Stamp"\nunit = "datetime"'))
    out = tmp_path / "abs.mcap"
    assert main(["import", str(f), "--map", str(mp), "--out", str(out), "--flight", "3"]) == 0
    _, names, v = _log(out)
    np.testing.assert_allclose(v[:, -1], rf.START.timestamp() + np.arange(n) / 1e3, atol=1e-6)
    from service.log.flightrec import flight_records

    (rec,) = flight_records(out)
    assert (rec.flight, rec.start_unix) == (3, rf.START.timestamp())


def test_scale_and_offset_in_the_columns_unit(tmp_path, healthy, capsys):
    """A gauge transducer in psi (offset 14.696 psi to absolute) and a position in inches
    with a scale of 2 (a half-scale channel): ``(scale * raw + offset) [unit] -> SI``."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    psi, inch = 6894.757293168361, 0.0254
    cols = {"Time": healthy["t"], "P_A_g": healthy["p1"] / psi - 14.696,
            "Ram_half": healthy["x_j"] / inch / 2}  # fmt: skip
    f = tmp_path / "g.parquet"
    pq.write_table(pa.table(cols), f)
    mp = tmp_path / "m.toml"
    mp.write_text('[time]\ncolumn = "Time"\n[actuator]\naircraft = "RIG1"\nname = "rudder"\n'
                  '[channels]\np1 = { column = "P_A_g", unit = "psi", offset = 14.696 }\n'
                  'x_j = { column = "Ram_half", unit = "in", scale = 2.0 }\n')  # fmt: skip
    out = tmp_path / "g.mcap"
    assert main(["import", str(f), "--map", str(mp), "--out", str(out)]) == 0
    _, names, v = _log(out)
    assert names == ("x_j", "p1", "seq", "t")  # the channels left out are absent
    np.testing.assert_allclose(v[:, 0], healthy["x_j"], rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(v[:, 1], healthy["p1"], rtol=1e-12)


def test_a_stock_reader_decodes_the_log(tmp_path, healthy, capsys):
    """What Foxglove does: the protobuf schema in the file, decoded by mcap's stock reader."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    f, mp = _write(tmp_path, "tdms", healthy)
    out = tmp_path / "run.mcap"
    assert main(["import", str(f), "--map", str(mp), "--out", str(out)]) == 0
    with open(out, "rb") as fh:
        rows = [(m.log_time, r) for _, _, m, r in
                make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]  # fmt: skip
    assert len(rows) == len(healthy["t"])
    lt, r = rows[10]
    assert r.seq == 10 and math.isclose(r.x_j, healthy["x_j"][10], rel_tol=1e-12)
    assert math.isclose(r.p1, healthy["p1"][10], rel_tol=1e-12)
    assert lt == round(r.t * 1e9)


def test_tdms_groups_at_two_rates(tmp_path, healthy, capsys):
    """A TDMS file of two groups: the rig at 1 kHz and a supply transducer at 2 kHz in a
    group of its own with its own waveform start; both on the one grid."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    f = rf.write_tdms(tmp_path / "two.tdms", healthy)
    t2 = np.arange(2 * len(healthy["t"])) / 2000.0
    sup = 205.0 + np.sin(2 * np.pi * 2.0 * t2)
    start = np.datetime64(rf.START.replace(tzinfo=None), "us")
    props = {"wf_increment": 0.0005, "wf_start_time": start, "wf_start_offset": 0.0}
    with TdmsWriter(f, mode="a") as w:
        w.write_segment([RootObject({}), GroupObject("Supply"),
                         ChannelObject("Supply", "P_S", sup, properties=props)])  # fmt: skip
    mp = tmp_path / "m.toml"
    mp.write_text(rf.map_text("tdms", "Rig/") + 'p_sr = { column = "Supply/P_S", unit = "bar" }\n')
    out = tmp_path / "two.mcap"
    assert main(["import", str(f), "--map", str(mp), "--out", str(out), "--json"]) == 0
    import json

    c = json.loads(capsys.readouterr().out)["imports"][0]["counts"]
    assert (c["copied"], c["downsampled"]) == (len(healthy["t"]), len(t2))
    _, names, v = _log(out)
    assert len(v) == len(healthy["t"]) and np.isfinite(v).all()  # both on every grid point
    t = v[:, names.index("t")] - rf.START.timestamp()
    ok = (t > 0.05) & (t < 1.45)
    want = 205e5 + 1e5 * np.sin(2 * np.pi * 2.0 * t[ok])
    np.testing.assert_allclose(v[ok, names.index("p_sr")], want, rtol=0, atol=0.01e5)
    np.testing.assert_allclose(v[:, names.index("x_j")], healthy["x_j"], rtol=1e-12)


def test_a_clock_that_steps_back_is_refused_by_the_intake(tmp_path, healthy, capsys):
    """Two TDMS groups with time channels; the supply's clock steps back 0.3 s: of the 300
    samples at times already passed, 5 are refused (as the replay's intake refuses them) and
    counted, the clock is followed at the 5th, and the grid keeps the values written first
    (the other 295 are ``overlap``)."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    t = healthy["t"][:1200]
    ts = np.r_[t[:1000], 0.7 + np.arange(500) / 1000.0]
    sup = np.r_[np.full(1000, 200.0), np.full(500, 300.0)]
    rig = {k: v[:1200] for k, v in rf.rig_columns(healthy).items()}
    f = tmp_path / "back.tdms"
    with TdmsWriter(f) as w:
        w.write_segment([RootObject({}), GroupObject("Rig"), GroupObject("Supply"),
                         ChannelObject("Rig", "Time", t),
                         *[ChannelObject("Rig", k, v) for k, v in rig.items()],
                         ChannelObject("Supply", "Time", ts), ChannelObject("Supply", "P_S", sup)])  # fmt: skip
    mp = tmp_path / "m.toml"
    mp.write_text(rf.map_text("tdms", "Rig/", '[time]\ncolumn = "Time"')
                  + 'p_sr = { column = "Supply/P_S", unit = "bar" }\n')  # fmt: skip
    out = tmp_path / "back.mcap"
    assert main(["import", str(f), "--map", str(mp), "--out", str(out), "--json"]) == 0
    import json

    c = json.loads(capsys.readouterr().out)["imports"][0]["counts"]
    assert c["intake"] == {"clock": 5, "restarts": 1, "refused": 5} and c["overlap"] == 295
    assert c["copied"] == 1200 + 1495
    _, names, v = _log(out)
    tt, p_sr = v[:, names.index("t")], v[:, names.index("p_sr")]
    assert np.all(p_sr[tt < 0.9995] == 200e5) and np.all(p_sr[tt > 0.9995] == 300e5)


@pytest.mark.parametrize("tz", ["UTC", "America/New_York"])
def test_csv_calendar_times_without_a_zone_are_utc(tmp_path, healthy, capsys, monkeypatch, tz):
    """ISO 8601 text times: one without a zone is UTC whatever the machine's zone; an
    offset is honoured (the log's times, hence its identity, never depend on the machine)."""
    import json
    import time

    import pyarrow as pa
    import pyarrow.csv as pcsv

    monkeypatch.setenv("TZ", tz)
    time.tzset()
    try:
        n = 300
        base = rf.START.timestamp()
        mp = tmp_path / "m.toml"
        mp.write_text(rf.map_text("csv", "", '[time]\ncolumn = "Stamp"\nunit = "datetime"'))
        cols = {k: v[:n] for k, v in rf.rig_columns(healthy).items()}
        t0 = {}
        for name, suffix in (("naive", ""), ("paris", "+02:00")):
            stamps = [time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(base + k // 1000))
                      + f".{k % 1000:03d}{suffix}" for k in range(n)]  # fmt: skip
            f = tmp_path / f"{name}.csv"
            pcsv.write_csv(pa.table({"Stamp": stamps, **cols}), f)
            out = tmp_path / f"{name}.mcap"
            assert main(["import", str(f), "--map", str(mp), "--out", str(out), "--json"]) == 0
            t0[name] = json.loads(capsys.readouterr().out)["imports"][0]["t0"]
        assert t0 == {"naive": base, "paris": base - 7200.0}
    finally:
        monkeypatch.undo()
        time.tzset()
