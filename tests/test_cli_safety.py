"""What a user can do wrong from the command line, and what the CLI does about it (issue 40):
an output that is an input is refused before anything is written (exit 2); a full disk, an
unwritable output, a read-only or damaged store, a foreign log end in one line on stderr
with the documented exit code (never a traceback); the reading commands open the store read
only (a read-only folder reads, nothing is migrated, a writer's lock is waited for at most
READ_TIMEOUT_S); bundled scenarios do not depend on the working directory; booleans are not
numbers in configs and scenarios."""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from test_store import make_period

import service
from service.cli import main
from service.cli.util import EXIT_IO, EXIT_USAGE, refuse_output_is_input
from service.store import open_store
from service.store.health import READ_TIMEOUT_S
from service.store.schema import MIGRATIONS, RECOMPUTE_TRENDS

ROOT = Path(service.__file__).resolve().parent.parent  # the code under test (children too)
ACT = "AC001/elevator_L"


def _one_line_error(err: str, *words: str) -> None:
    """stderr holds exactly one ``servowatch: error:`` line with ``words``, no traceback."""
    lines = [ln for ln in err.splitlines() if ln.startswith("servowatch: error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err, err
    for w in words:
        assert w in lines[0], (w, lines[0])


def _cli(*argv: str, cwd: Path | None = None, prefix: list[str] | None = None, timeout=120):
    """``servowatch ARGV`` in a child process (this worktree's code)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [*(prefix or []), sys.executable, "-m", "service.cli", *argv]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=cwd or ROOT, env=env,
                          timeout=timeout)  # fmt: skip


@pytest.fixture(scope="module")
def healthy_meas(tmp_path_factory):
    """The measured arrays of a 1.5 s healthy bench run (HF, seeded sensor noise)."""
    from service.monitor.calibration import measured_run
    from service.sim.scenarios import load_scenario

    sc = tmp_path_factory.mktemp("sc") / "h.toml"
    sc.write_text(
        'name = "h"\nduration_s = 1.5\n[command]\ninitial = 0.0\nperiodic = ['
        '{ kind = "sine", amplitude = 0.002, freq_hz = 0.3 }]\n[load]\ninitial = 4000.0\n'
        "[sensors]\nseed = 7\n"
    )
    _, meas = measured_run(load_scenario(sc))
    return meas


def _foreign_log(path: Path, rows: list[tuple[float, bytes]]) -> Path:
    """An MCAP log as another acquisition system writes it: raw JSON payloads on
    ``/fleet/AC001/elevator_L/meas`` at the given log times."""
    from mcap.writer import CompressionType, Writer

    with open(path, "wb") as fh:
        w = Writer(fh, compression=CompressionType.NONE)
        w.start()
        sid = w.register_schema("meas", "jsonschema", b"{}")
        cid = w.register_channel(f"/fleet/{ACT}/meas", "json", sid)
        for k, (t, data) in enumerate(rows):
            ns = int(round(t * 1e9))
            w.add_message(cid, log_time=ns, data=data, publish_time=ns, sequence=k)
        w.finish()
    return path


def _meas_rows(meas: dict, times=None) -> list[tuple[float, bytes]]:
    keys = ("x_cmd", "i", "x_s", "x_j", "p1", "p2")
    t = meas["t"] if times is None else times
    return [
        (float(t[j]), json.dumps({k: float(meas[k][j]) for k in keys}).encode())
        for j in range(len(meas["t"]))
    ]


@pytest.fixture
def small_store(tmp_path) -> Path:
    p = tmp_path / "health.sqlite"
    with open_store(p) as s:
        s.add_periods([make_period(ACT, k) for k in range(6)])
    return p


# ------------------------------------------------------------- 3. inputs are never written


def _bench_log(path: Path) -> Path:
    from service.log import McapLogger
    from service.wire.messages import mcap_topic

    with McapLogger(path, background_flush=False) as lg:
        for k in range(300):
            t = 1e-3 * k
            lg.log(mcap_topic("AC001", "elevator_L", "meas"), t,
                   {"seq": k, "t": t, "x_cmd": 0.0, "i": 0.0, "x_s": 0.0, "x_j": 0.0,
                    "p1": 1e7, "p2": 1e7})  # fmt: skip
    return path


@pytest.mark.parametrize("how", ["same", "symlink", "hardlink", "dotdot"])
def test_replay_out_that_is_its_input_is_refused_and_the_log_kept(tmp_path, how, capsys):
    log = _bench_log(tmp_path / "in.mcap")
    before = log.read_bytes()
    out = {"same": log, "dotdot": tmp_path / "sub" / ".." / "in.mcap"}.get(how)
    if how == "symlink":
        out = tmp_path / "link.mcap"
        out.symlink_to(log)
    if how == "hardlink":
        out = tmp_path / "hard.mcap"
        os.link(log, out)
    (tmp_path / "sub").mkdir()
    assert main(["replay", str(log), "--out", str(out)]) == EXIT_USAGE
    _one_line_error(capsys.readouterr().err, "--out", "input", str(log))
    assert log.read_bytes() == before  # today: 9.7 MB -> 2 kB, exit 0


def test_outputs_that_are_inputs_are_refused_by_every_writing_command(
    tmp_path, small_store, capsys
):
    sc = tmp_path / "h.toml"
    sc.write_text('name = "h"\nduration_s = 0.2\n')
    log = _bench_log(tmp_path / "in.mcap")
    store_link = tmp_path / "store-link.png"
    store_link.symlink_to(small_store)
    station = tmp_path / "station.toml"
    station.write_text('station = "s1"\n')
    inp, both = "refusing to overwrite an input", "is also the output"
    cases = [
        (["estimate", "--scenario", str(sc), "--png", str(sc)], inp),
        (["estimate", "--scenario", str(sc), "--out", str(tmp_path / "o.mcap"),
          "--png", str(tmp_path / "o.mcap")], both),
        (["simulate", "--scenario", str(sc), "--valve", "HF", "--out", str(sc)], inp),
        (["compare", "--scenario", str(sc), "--png", str(sc)], inp),
        (["calibrate", "--log", str(log), "--out", str(log)], inp),
        (["calibrate", "--scenario", str(sc), "--actuator", ACT, "--store", str(sc)], inp),
        (["rul", "--store", str(small_store), "--png", str(store_link)], inp),
        (["fleet-sim", "--store", str(small_store), "--truth", str(store_link)], both),
        (["demo", "--scenario", str(sc), "--out", str(sc)], inp),
        (["web", "--store", str(small_store), "--snapshot", str(store_link)], inp),
        (["replay", str(log), "--store", str(log)], inp),
        (["run", "--config", str(station), "--log", str(station)], inp),
    ]  # fmt: skip
    guarded = {p: p.read_bytes() for p in (sc, log, small_store, station)}
    for argv, why in cases:
        assert main(argv) == EXIT_USAGE, argv
        _one_line_error(capsys.readouterr().err, why)
        for p, b in guarded.items():
            assert p.read_bytes() == b, (argv, p)


def test_refuse_output_is_input_compares_files_not_names(tmp_path):
    a = tmp_path / "a.mcap"
    a.write_bytes(b"x")
    b = tmp_path / "b.mcap"
    b.write_bytes(b"x")  # same content, another file: not the input
    assert refuse_output_is_input([("--out", b)], [("LOG", a)]) is None
    assert refuse_output_is_input([("--out", None)], [("LOG", a)]) is None
    assert refuse_output_is_input([("--store", "postgresql://u@h/db")], [("LOG", a)]) is None
    os.link(a, tmp_path / "h.mcap")
    assert "a link to it" in refuse_output_is_input([("--out", tmp_path / "h.mcap")],
                                                    [("LOG", a)])  # fmt: skip


# ------------------------------------------------------------ 6. one line, never a traceback


def test_full_disk_is_one_line_and_exit_5(tmp_path, capsys):
    assert main(["characteristic", "--model", "C5", "--png", "/dev/full"]) == EXIT_IO
    _one_line_error(capsys.readouterr().err, "--png /dev/full", "No space left on device")
    sc = tmp_path / "h.toml"
    sc.write_text('name = "h"\nduration_s = 0.2\n')
    assert main(["estimate", "--scenario", str(sc), "--out", "/dev/full"]) == EXIT_IO
    _one_line_error(capsys.readouterr().err, "--out /dev/full", "No space left on device")


def test_unwritable_outputs_are_refused_before_the_work(tmp_path, capsys):
    sc = tmp_path / "h.toml"
    sc.write_text('name = "h"\nduration_s = 0.2\n')
    a_file = tmp_path / "file"
    a_file.write_text("x")
    cases = [
        (["estimate", "--scenario", str(sc), "--png", str(tmp_path / "no" / "p.png")], "--png"),
        (["estimate", "--scenario", str(sc), "--out", str(a_file / "o.mcap")], "--out"),
        (["calibrate", "--scenario", str(sc), "--out", str(tmp_path)], "--out"),
        (["fleet-sim", "--actuators", "1", "--flights", "2", "--store",
          str(tmp_path / "f.sqlite"), "--logs", str(a_file / "logs")], "--logs"),
        (["fleet-sim", "--actuators", "1", "--flights", "2", "--store",
          str(tmp_path / "f.sqlite"), "--truth", str(tmp_path / "no" / "t.json")], "--truth"),
        (["rul", "--store", str(tmp_path / "none.sqlite"), "--png", str(tmp_path)], "--png"),
    ]  # fmt: skip
    for argv, flag in cases:
        t0 = time.perf_counter()
        assert main(argv) == EXIT_USAGE, argv
        _one_line_error(capsys.readouterr().err, flag)
        assert time.perf_counter() - t0 < 5.0, argv  # refused before the run, not after
    assert not (tmp_path / "f.sqlite").exists()  # nothing written


@pytest.fixture
def open_dir():
    """A folder any user may write (for the unprivileged child), removed afterwards."""
    d = Path(tempfile.mkdtemp(prefix="servowatch-ro-"))
    d.chmod(0o777)
    try:
        yield d
    finally:
        shutil.rmtree(d, ignore_errors=True)


def test_read_only_store_file_is_refused_before_the_work(open_dir):
    store = open_dir / "health.sqlite"
    with open_store(store) as s:
        s.add_periods([make_period(ACT, k) for k in range(6)])
    for side in ("-wal", "-shm"):
        (open_dir / f"health.sqlite{side}").unlink(missing_ok=True)
    store.chmod(0o444)
    before = store.read_bytes()
    # the file mounted read only in a private mount namespace: root cannot write it either
    # (a child switched to another user could not read this checkout where it is private)
    ro = [*_read_only_mount(), str(store)]
    r = _cli("rul", "--store", str(store), prefix=ro)
    assert r.returncode == EXIT_USAGE, r.stderr
    _one_line_error(r.stderr, str(store), "cannot be written")
    assert "threshold" not in r.stdout  # refused before the fits, not after
    assert store.read_bytes() == before
    # read only, the same store reads
    r = _cli("rul", "--store", str(store), "--no-save", "--json", prefix=ro)
    assert r.returncode == 0, r.stderr
    assert [a["actuator"] for a in json.loads(r.stdout)["actuators"]] == [ACT]


def test_damaged_store_is_one_line_naming_it(small_store, capsys):
    with open(small_store, "r+b") as f:  # pages 3-5: the tables' b-trees
        f.seek(2 * 4096)
        f.write(b"\xff" * 3 * 4096)
    for cmd in (["fleet"], ["baselines"], ["rul", "--no-save"], ["rul"]):
        code = main([*cmd, "--store", str(small_store)])
        assert code in (EXIT_USAGE, EXIT_IO), cmd
        _one_line_error(capsys.readouterr().err, str(small_store))
    junk = small_store.with_name("junk.sqlite")
    junk.write_bytes(bytes(range(256)) * 8)
    assert main(["fleet", "--store", str(junk)]) == EXIT_USAGE
    _one_line_error(capsys.readouterr().err, str(junk), "not a database")


def test_calibrate_refuses_foreign_payloads_with_one_line(tmp_path, healthy_meas, capsys):
    rows = _meas_rows(healthy_meas)
    cases = {
        "constant": ([(5.0, d) for _, d in rows], "usable samples"),
        "list": (rows[:10] + [(rows[10][0], b"[1, 2, 3]")] + rows[11:], "not an object"),
        "number": (rows[:10] + [(rows[10][0], b"42")] + rows[11:], "not an object"),
        "text": (rows[:10] + [(rows[10][0], json.dumps({**json.loads(rows[10][1]),
                 "p1": "high"}).encode())] + rows[11:], "p1 = 'high' is not a number"),
        "bool": (rows[:10] + [(rows[10][0], json.dumps({**json.loads(rows[10][1]),
                 "x_s": True}).encode())] + rows[11:], "x_s = True is not a number"),
    }  # fmt: skip
    for name, (rws, why) in cases.items():
        log = _foreign_log(tmp_path / f"{name}.mcap", rws)
        out = tmp_path / f"{name}.json"
        code = main(["calibrate", "--log", str(log), "--passes", "0", "--out", str(out)])
        assert code == EXIT_USAGE, name
        _one_line_error(capsys.readouterr().err, str(log), why)
        assert not out.exists()


def test_calibrate_drops_repeated_timestamps_as_the_intake_does(
    tmp_path, healthy_meas, capsys, monkeypatch
):
    # calibrate records the log's unit in the default store: this test's own, not the
    # session's (the e2e daemons of the same unit would monitor on this baseline)
    monkeypatch.setenv("SERVOWATCH_STORE", str(tmp_path / "health.sqlite"))
    rows = _meas_rows(healthy_meas)
    clean = _foreign_log(tmp_path / "clean.mcap", rows)
    twice = _foreign_log(tmp_path / "twice.mcap", [r for r in rows for _ in (0, 1)])
    outs = []
    for log in (clean, twice):
        assert main(["calibrate", "--log", str(log), "--passes", "0", "--json"]) == 0
        cap = capsys.readouterr()
        outs.append(json.loads(cap.out)["baseline"])
    assert f"dropped {len(rows)} of {2 * len(rows)} samples" in cap.err
    for k in ("x_ss", "g_pq", "p_r", "c_lk"):
        assert outs[1][k] == outs[0][k], k  # the duplicates add nothing


# ------------------------------------------------------- 7. read-only commands, read only


def _read_only_mount() -> list[str]:
    """A prefix that runs a command with ``$FOLDER`` (its first argument) mounted read only
    (a private mount namespace: root cannot write it either)."""
    probe = subprocess.run(["unshare", "-rm", "true"], capture_output=True)
    if shutil.which("unshare") is None or probe.returncode != 0:
        pytest.skip("no user/mount namespaces (unshare -rm) to mount a folder read only")
    return ["unshare", "-rm", "sh", "-c",
            'mount --bind "$0" "$0" && mount -o remount,bind,ro "$0" && exec "$@"']  # fmt: skip


def test_fleet_reads_a_store_in_a_read_only_folder(small_store):
    folder = small_store.parent
    for side in ("-wal", "-shm"):
        (folder / f"health.sqlite{side}").unlink(missing_ok=True)
    ro = _read_only_mount()
    got = {}
    for cmd in (["fleet", "--json"], ["baselines", "--json"], ["rul", "--no-save", "--json"]):
        r = _cli(*cmd, "--store", str(small_store), prefix=[*ro, str(folder)])
        assert r.returncode == 0, (cmd, r.stderr)  # today: "unable to open database file"
        got[cmd[0]] = json.loads(r.stdout)
    assert got["fleet"]["fleet"][0]["periods"] == 6
    assert got["baselines"]["uncommissioned"] == [ACT]
    assert [a["actuator"] for a in got["rul"]["actuators"]] == [ACT]
    assert sorted(p.name for p in folder.iterdir()) == ["health.sqlite"]  # nothing created
    # a writer there: one line before the work
    r = _cli("rul", "--store", str(small_store), prefix=[*ro, str(folder)])
    assert r.returncode == EXIT_USAGE
    _one_line_error(r.stderr, str(small_store))


def test_reading_commands_never_migrate_an_empty_file(tmp_path, capsys):
    empty = tmp_path / "health.sqlite"
    empty.touch()
    for cmd in (["fleet"], ["baselines"], ["rul", "--no-save"], ["rul"]):
        assert main([*cmd, "--store", str(empty)]) == EXIT_USAGE, cmd
        _one_line_error(capsys.readouterr().err, str(empty))
        assert empty.stat().st_size == 0, cmd


def _old_store(url: str) -> None:
    """A store at schema version 2 (as an older servowatch left it)."""
    if url.startswith("postgresql://"):
        import psycopg

        conn = psycopg.connect(url, autocommit=True)
    else:
        conn = sqlite3.connect(url, isolation_level=None)
    conn.execute("CREATE TABLE schema_migrations (version INTEGER PRIMARY KEY, "
                 "description TEXT NOT NULL, applied_s DOUBLE PRECISION NOT NULL)")  # fmt: skip
    for version, desc, stmts in MIGRATIONS[:2]:
        for s in stmts:
            if s != RECOMPUTE_TRENDS:
                conn.execute(s)
        conn.execute(f"INSERT INTO schema_migrations VALUES ({version}, '{desc}', 0)")
    conn.execute(f"INSERT INTO actuators VALUES ('{ACT}', 0)")
    conn.close()


def _schema_version(url: str) -> int:
    if url.startswith("postgresql://"):
        import psycopg

        with psycopg.connect(url) as c:
            return c.execute("SELECT MAX(version) FROM schema_migrations").fetchone()[0]
    with sqlite3.connect(url) as c:
        return c.execute("SELECT MAX(version) FROM schema_migrations").fetchone()[0]


def test_reading_commands_never_migrate_an_older_schema(store_url, capsys):
    _old_store(store_url)
    for cmd in (["fleet"], ["baselines"], ["rul", "--no-save"]):
        assert main([*cmd, "--store", store_url]) == EXIT_USAGE, cmd
        _one_line_error(capsys.readouterr().err, "schema version 2")
        assert _schema_version(store_url) == 2, cmd


def test_fleet_does_not_wait_for_a_writer_longer_than_the_timeout(small_store):
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sqlite3, sys, time; c = sqlite3.connect(sys.argv[1], isolation_level=None); "
         "c.execute('BEGIN EXCLUSIVE'); c.execute('DELETE FROM periods WHERE start_t < 0'); "
         "print('locked', flush=True); time.sleep(60)", str(small_store)],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "locked"
        t0 = time.perf_counter()
        r = _cli("fleet", "--json", "--store", str(small_store), timeout=60)
        wall = time.perf_counter() - t0
    finally:
        holder.kill()
        holder.wait()
    assert wall < READ_TIMEOUT_S + 5.0, wall  # today: 30 s, then a traceback
    assert r.returncode == 0, r.stderr  # WAL: a reader does not wait for the writer at all
    assert json.loads(r.stdout)["fleet"][0]["periods"] == 6


# ------------------------------------------------- last bullet: demo, scenarios, booleans


def test_bundled_scenarios_do_not_depend_on_the_working_directory(tmp_path, monkeypatch):
    from service.sim.scenarios import SCENARIO_DIR, load_scenario, resolve_scenario

    (tmp_path / "demo").mkdir()  # a folder named like the demo's scenario
    (tmp_path / "healthy_noise").write_text("not a scenario")  # fleet-sim's
    monkeypatch.chdir(tmp_path)
    assert resolve_scenario("demo") == SCENARIO_DIR / "demo.toml"
    assert load_scenario("healthy_noise").duration_s > 0
    assert load_scenario("demo").name == "demo"
    (tmp_path / "mine.toml").write_text('name = "mine"\nduration_s = 0.3\n')
    assert load_scenario("mine.toml").duration_s == 0.3  # a path is a path
    with pytest.raises(ValueError, match="not a scenario file"):
        resolve_scenario("./demo")


def test_booleans_in_numeric_fields_are_refused_naming_file_and_field(tmp_path, capsys):
    from service.config import ConfigError, load_config
    from service.sim.scenarios import ScenarioError, load_scenario

    cases = {
        "rotate_bytes = true\n": "rotate_bytes",
        "[monitor]\narm_s = false\n": "monitor.arm_s",
        "[clock]\nresync_n = true\n": "clock.resync_n",
    }
    for text, field in cases.items():
        p = tmp_path / "station.toml"
        p.write_text(text)
        with pytest.raises(ConfigError, match=f"{p}: {field}: expected a number"):
            load_config(p, environ={})
        assert main(["run", "--config", str(p), "--duration", "0.1"]) == EXIT_USAGE
        _one_line_error(capsys.readouterr().err, str(p), field)
    assert load_config(None, environ={"SERVOWATCH_ROTATE_BYTES": "1000"}).rotate_bytes == 1000
    sc = tmp_path / "b.toml"
    for text, field in (("duration_s = true\n", "duration_s"),
                        ("duration_s = 1.0\n[sensors]\nseed = true\n", "sensors.seed"),
                        ('duration_s = 1.0\n[command]\nevents = [{ t = true, kind = "step", '
                         "value = 0.001 }]\n", "command.events.0.t")):  # fmt: skip
        sc.write_text(text)
        with pytest.raises(ScenarioError, match=field.replace(".", r"\.")):
            load_scenario(sc)
        assert main(["estimate", "--scenario", str(sc)]) == EXIT_USAGE
        _one_line_error(capsys.readouterr().err, str(sc))
    sc.write_text("duration_s = 1\n[sensors]\nseed = 3\n")  # integers stay numbers
    assert load_scenario(sc).duration_s == 1.0


def _tiny_disk() -> list[str]:
    """A prefix that runs a command with ``$FOLDER`` (its first argument) a 200 kB file
    system (a full disk within seconds)."""
    probe = subprocess.run(["unshare", "-rm", "true"], capture_output=True)
    if shutil.which("unshare") is None or probe.returncode != 0:
        pytest.skip("no user/mount namespaces (unshare -rm) for a small file system")
    return ["unshare", "-rm", "sh", "-c",
            'mount -t tmpfs -o size=200k none "$0" && exec "$@"']  # fmt: skip


@pytest.mark.slow
def test_demo_whose_log_fails_exits_non_zero_and_says_so(tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    r = _cli("demo", "--duration", "4", "--inject-at", "1", "--out", str(disk / "demo.mcap"),
             "--plot", "", "--json", prefix=[*_tiny_disk(), str(disk)], timeout=180)  # fmt: skip
    assert r.returncode == EXIT_IO, (r.returncode, r.stderr[-2000:])
    summary = json.loads(r.stdout)
    assert summary["log_failure"] and "No space left" in summary["log_failure"]
    assert "Traceback" not in r.stderr
    assert "the MCAP log failed" in r.stderr


def test_fleet_on_postgresql_waits_for_a_writers_lock_at_most_the_timeout(pg_cluster):
    if pg_cluster is None:
        if os.environ.get("SERVOWATCH_REQUIRE_PG") == "1":
            pytest.fail("PostgreSQL required (SERVOWATCH_REQUIRE_PG=1)")
        pytest.skip("PostgreSQL tests skipped: no server binaries")
    import psycopg

    url = pg_cluster.create_database()
    with open_store(url) as s:
        s.add_periods([make_period(ACT, k) for k in range(6)])
    with psycopg.connect(url) as writer:  # a migration's lock, held
        writer.execute("LOCK TABLE summary IN ACCESS EXCLUSIVE MODE")
        t0 = time.perf_counter()
        r = _cli("fleet", "--json", "--store", url, timeout=60)  # today: waits for ever
        wall = time.perf_counter() - t0
        writer.rollback()
    assert r.returncode == EXIT_USAGE, r.stderr
    _one_line_error(r.stderr, "is busy")
    assert READ_TIMEOUT_S <= wall < READ_TIMEOUT_S + 10.0, wall
    assert json.loads(_cli("fleet", "--json", "--store", url).stdout)["fleet"][0]["periods"] == 6
