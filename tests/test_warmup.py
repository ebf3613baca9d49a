"""The first-run compile says what it does (issue 34): ``servowatch warmup`` on an empty numba
cache announces the compile with an estimate and prints a line per compiled kernel; once
cached, the same command and ``ensure`` are silent."""

from __future__ import annotations

import io
import os
import re
import subprocess

import pytest

from evaluation.restart import servowatch_exe


def _warmup(cache_dir, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir)}
    return subprocess.run(
        [*servowatch_exe(), "warmup", *args], capture_output=True, text=True, timeout=900,
        env=env,
    )  # fmt: skip


@pytest.mark.slow
def test_a_cold_compile_is_announced_then_cached(tmp_path):
    r = _warmup(tmp_path, "--group", "models")
    assert r.returncode == 0, r.stderr
    m = re.search(r"compiling the HF bench kernels \(first run, about (\d+) s", r.stderr)
    assert m and int(m.group(1)) > 0, r.stderr
    assert "compiled models.compiled._integrate_hf" in r.stderr, r.stderr
    assert any(p.suffix == ".nbi" for p in tmp_path.rglob("*")), "nothing cached"
    again = _warmup(tmp_path, "--group", "models")
    assert again.returncode == 0, again.stderr
    assert "compiling" not in again.stderr and "compiled kernels ready" in again.stderr


@pytest.mark.slow
def test_the_trend_group_compiles_the_rul_trend_kernel_on_its_own(tmp_path):
    """``rul --robust-trend``'s kernel (issue 55, opt-in): its own group, not a default one;
    announced and compiled cold, then cached."""
    from service.cli.warmup import DEFAULT_GROUPS

    assert "trend" not in DEFAULT_GROUPS
    r = _warmup(tmp_path, "--group", "trend")
    assert r.returncode == 0, r.stderr
    assert "compiling the RUL's trend model kernel" in r.stderr, r.stderr
    assert "compiled service.prognostics.trend._kalman" in r.stderr, r.stderr
    again = _warmup(tmp_path, "--group", "trend")
    assert again.returncode == 0 and "compiling" not in again.stderr, again.stderr


def test_ensure_is_silent_when_cached():
    from service.cli.warmup import ensure, is_cached

    if not is_cached("log"):
        pytest.skip("the log kernels are not compiled here (run `servowatch warmup`)")
    out = io.StringIO()
    ensure("log", stream=out)
    assert out.getvalue() == ""


def test_warmup_help_names_the_groups():
    r = subprocess.run([*servowatch_exe(), "warmup", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "valves" in r.stdout, r.stderr


@pytest.mark.slow
def test_a_parallel_cold_warmup_compiles_each_kernel_once(tmp_path):
    """Two processes: the UKF steps compile beside the log's kernels, and the rest of the
    monitor loads them from the cache (its argument types are those of ``step_one``); no
    kernel is compiled twice."""
    import json

    r = _warmup(tmp_path, "--group", "monitor", "--group", "log", "--jobs", "2", "--table",
                "--json")  # fmt: skip
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)["kernels"]
    names = [k["kernel"] for k in rows]
    for k in ("service.monitor.ukf.ukf_one", "service.monitor.ukf.ukf_one_wh",
              "service.monitor.kernels.step_one", "service.log.codec_read._objects"):  # fmt: skip
        assert names.count(k) == 1, (k, names)
    assert all(
        k["signatures"] == 1 for k in rows if k["kernel"].startswith("service.monitor.ukf.ukf_")
    )
    again = _warmup(tmp_path, "--group", "monitor", "--group", "log", "--jobs", "2")
    assert again.returncode == 0 and "compiling" not in again.stderr, again.stderr


def test_the_log_paths_run_on_the_signatures_the_warmup_compiles():
    """The reader parses chunk bytes (read-only) or arrays of its own (writable): the
    kernels see one signature either way, the warm-up's, so no command compiles a second
    one on its first run (it did: 3 s into the first demo, 13 s in its plot)."""
    from numba.core import event

    from service.cli.warmup import GROUPS, _listener
    from service.log.codec import json_records, parse_objects, scan_records

    GROUPS["log"]()  # compiled, or loaded from the cache
    compiled: list[str] = []
    recs = json_records([b'{"seq":1,"x":0.5,"y":-2.25}', b'{"seq":2,"x":null,"y":1e+300}'])
    with event.install_listener("numba:compile", _listener(
        lambda ev: compiled.append(ev.data["dispatcher"].py_func.__qualname__), lambda ev: None
    )):  # fmt: skip
        for buf in (recs, recs.copy()):  # read-only, writable
            _, starts, lens, _, _ = scan_records(buf)
            assert parse_objects(buf, starts + 22, lens - 22) is not None
    assert compiled == []
