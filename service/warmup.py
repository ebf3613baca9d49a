"""Compile and cache the numba kernels once (``python -m service.warmup``).

``make`` runs this right after installing, so the first ``servowatch demo`` or test run does
not spend its first seconds compiling. Safe to run any time; it only exercises the kernels.
"""

from __future__ import annotations

import sys
import time

__all__ = ["warm_up"]


def warm_up() -> float:
    """Run every compiled path briefly; return the wall time taken [s]."""
    t0 = time.perf_counter()
    from models.eha import VALVE_MODELS, EHAStepper, simulate
    from models.params import EHAParams
    from models.scenario import Scenario
    from service.messages import decode_meas_arrays, encode_meas
    from service.monitor import Monitor, MonitorBank

    sc = Scenario(name="warmup", duration_s=2e-3, step_s=1e-4)
    for valve in VALVE_MODELS:
        simulate(sc, valve)
    st = EHAStepper(EHAParams(), "HF")
    samples = []
    for k in range(20):
        st.advance(10, 0.001, 0.0, 20e6, 2e-13)
        s = st.signals()
        samples.append({**s, "t": 1e-3 * k})
    mon = Monitor()
    for s in samples:
        mon.update(s)
    bank = MonitorBank()
    bank.update_rows([("a", s) for s in samples[:1]])
    for s in samples[1:]:
        bank.update_rows([("a", s)])
    arr = decode_meas_arrays(encode_meas([{**s, "seq": k} for k, s in enumerate(samples)]))
    bank.update_arrays([bank.index_of("b")] * len(arr.t), arr.t, arr.values)
    from service.log import codec as logcodec

    logcodec.warm_up()
    return time.perf_counter() - t0


if __name__ == "__main__":
    dt = warm_up()
    print(f"servowatch: compiled kernels ready ({dt:.1f} s)", file=sys.stderr)
