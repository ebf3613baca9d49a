"""Router restarts mid-stream, every piece in its own process on loopback (issue 10): the
stream resumes soon after the router's return and no sample the publisher's cache held is
lost (seq continuity in the daemon's MCAP log and its status counters)."""

from __future__ import annotations

import pytest

from evaluation.restart import run_restart

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("link", ["actuator", "daemon"])
def test_router_kill_and_restart_loses_no_cached_sample(tmp_path, link):
    r = run_restart(tmp_path, link=link, down_s=1.0, before_s=2.0, after_s=2.0)
    # generous bounds for a loaded machine; the figures: bench/restart.py
    assert r["resume_s"] is not None and r["resume_s"] < 5.0, r  # from the router listening
    assert r["flowing_s"] < 10.0, r  # from its spawn (servowatch router's start included)
    assert r["lost"] == 0 and r["gaps"] == 0 and r["missed"] == 0, r
    assert r["logged"] == r["last_seq"] + 1 and r["bad"] == {}, r


_PUBLISHER = """
import sys, time, zenoh
from service.wire import messages as m
from service.sim.actuator import VirtualActuator
from service.sim.scenarios import load_scenario
from service.zenoh_util import make_config
va = VirtualActuator(load_scenario("demo"), rate_hz=1000.0, t_origin=time.time())
samples = va.produce(3000)
s = zenoh.open(make_config("client", connect=[sys.argv[1]]))
key = "fleet/AC001/elevator_L/meas"
time.sleep(1.0)
for j in range(0, 3000, 10):
    s.put(key, m.encode_meas(samples[j : j + 10]))
    if j == 1000:  # the issue's case: one valid sample 1e6 s in the future
        s.put(key, m.encode_meas([dict(samples[j + 10], t=samples[j + 10]["t"] + 1e6)]))
    time.sleep(0.005)
time.sleep(0.5)
s.close()
"""


def test_one_sample_far_in_the_future_costs_that_sample_only(tmp_path):
    import subprocess
    import sys

    from tests.test_service_e2e import Net, act_samples, read, start_daemon

    net = Net()
    try:
        log = tmp_path / "clock.mcap"
        d = start_daemon(net, log)
        pub = subprocess.Popen([sys.executable, "-c", _PUBLISHER, net.ep])
        net.procs.append(pub)
        assert pub.wait(120) == 0
        st = net.wait(lambda s: act_samples(s) >= 3000, 120, "every good sample")
        a = st["actuators"]["fleet/AC001/elevator_L/meas"]
        assert a["samples"] == 3000 and a["bad"] == {"clock": 1}, a
        d.terminate()
        assert d.wait(60) == 0
        rows, _ = read(log, ["/fleet/AC001/elevator_L/meas"])
        seqs = [int(r[2]["seq"]) for r in rows]
        assert sorted(seqs) == list(range(3000))  # every good sample logged, the bad one not
    finally:
        net.close()
