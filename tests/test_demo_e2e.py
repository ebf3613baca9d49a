"""``servowatch demo``, the README's first command, end to end: a router on a free loopback
port, the virtual HF actuator with a leak injected, the monitoring daemon, its MCAP log and
plot, and the summary it prints."""

from __future__ import annotations

import json
import subprocess

import pytest

from evaluation.restart import servowatch_exe
from service.log import read_log


@pytest.mark.slow
def test_the_demo_detects_the_injected_leak_and_logs_it(tmp_path):
    log, png = tmp_path / "demo.mcap", tmp_path / "demo.png"
    r = subprocess.run(
        [*servowatch_exe(), "demo", "--duration", "8", "--inject-at", "3", "--out", str(log),
         "--plot", str(png), "--json"],
        capture_output=True, text=True, timeout=240, cwd=tmp_path,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    s = json.loads(r.stdout)
    assert s["fault"]["ok"], s["fault"]
    # 8 s at 1 kHz, every sample logged and none malformed
    assert s["samples"] >= 7000 and s["dropped"] == 0 and s["bad"] == 0, s
    # the default leak is 4x nominal: the alarm (raise at 2.5x) comes within a second of it
    assert s["leak_detected_after_s"] is not None and 0 <= s["leak_detected_after_s"] < 1.0, s
    assert 3.0 < s["leak_ratio_final"] < 5.0, s
    assert "leak" in s["alarms_active"], s
    assert png.stat().st_size > 10_000
    # the log holds the measurements and the monitor's estimates, with the leak read there
    counts: dict[str, int] = {}
    c_lk_last = None
    for topic, _, msg in read_log(log):
        kind = topic.rsplit("/", 1)[-1]
        counts[kind] = counts.get(kind, 0) + 1
        if kind == "est":
            c_lk_last = msg.get("c_lk")
    assert counts.get("meas", 0) >= 7000 and counts.get("est", 0) > 0, counts
    assert c_lk_last is not None and c_lk_last > 2.5 * 2e-13, c_lk_last
