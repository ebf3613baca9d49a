"""Router restarts mid-stream, every piece in its own process on loopback (issue 10): the
stream resumes soon after the router's return and no sample the publisher's cache held is
lost (seq continuity in the daemon's MCAP log and its status counters)."""

from __future__ import annotations

import pytest

from service.restart_harness import run_restart

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("link", ["actuator", "daemon"])
def test_router_kill_and_restart_loses_no_cached_sample(tmp_path, link):
    r = run_restart(tmp_path, link=link, down_s=1.0, before_s=2.0, after_s=2.0)
    assert r["resume_s"] is not None and r["resume_s"] < 5.0, r  # generous bound; bench/restart.py
    assert r["lost"] == 0 and r["gaps"] == 0 and r["missed"] == 0, r
    assert r["logged"] == r["last_seq"] + 1 and r["bad"] == {}, r
