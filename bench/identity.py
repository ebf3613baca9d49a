"""Cost of a log's stream identity (service/store/identity.py, decision record 0033): a
unit's accepted samples through ``StreamDigest`` (per-sample mix, content-defined blocks,
BLAKE2b per block and per run) beside a plain BLAKE2b of the same bytes, and the identity's
stored size. ``--stored K`` compares the stream with K stored streams while it is read.

    .venv/bin/python bench/identity.py [--samples 1000000] [--stored 8] [--replay-s 60]
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
if "service" in sys.modules and not hasattr(sys.modules["service"], "__path__"):
    del sys.modules["service"]  # bench/service.py, not the package

from service.store.identity import StreamDigest  # noqa: E402


def _best(fn, n: int = 3) -> float:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return min(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--stored", type=int, default=8)
    ap.add_argument("--block", type=int, default=512, help="samples per read block")
    ap.add_argument("--replay-s", type=float, default=0.0,
                    help="also replay a log of this many seconds (1 kHz) with and without "
                         "the identity")  # fmt: skip
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    x = np.column_stack([np.arange(a.samples) * 1e-3, rng.normal(size=(a.samples, 7))])
    stored = {}
    for k in range(a.stored):  # other logs of the unit: pieces of this one and strangers
        d = StreamDigest()
        lo = (k * a.samples) // max(a.stored, 1)
        d.add(x[lo : lo + a.samples // 10] if k % 2 else x[lo : lo + 5000] + 1.0)
        stored[f"s{k}"] = d.finish()

    def digest() -> None:
        d = StreamDigest(stored)
        for i in range(0, a.samples, a.block):
            d.add(x[i : i + a.block])
        sid = d.finish()
        for s in stored:
            d.relation(sid, s)

    def plain() -> None:
        h = hashlib.blake2b(digest_size=16)
        for i in range(0, a.samples, a.block):
            h.update(x[i : i + a.block].tobytes())
        h.hexdigest()

    d = StreamDigest()
    d.add(x)
    sid = d.finish()
    tp, td = _best(plain), _best(digest)
    print(f"{a.samples} samples (8 float64 each), read blocks of {a.block}, "
          f"{a.stored} stored streams compared")  # fmt: skip
    print(f"{'contender':<34}{'wall s':>10}{'M samples/s':>14}")
    print(f"{'plain BLAKE2b of the bytes':<34}{tp:>10.3f}{a.samples / tp / 1e6:>14.2f}")
    print(f"{'StreamDigest (blocks, relations)':<34}{td:>10.3f}{a.samples / td / 1e6:>14.2f}")
    blocks = sum(len(r.blocks) for r in sid.runs)
    print(f"blocks {blocks} (mean {a.samples / max(blocks, 1):.0f} samples), stored identity "
          f"{len(sid.dumps())} bytes ({len(sid.dumps()) / a.samples:.3f} B/sample)")  # fmt: skip
    if a.replay_s > 0:
        replay_contenders(a.replay_s)


class _NoIdentity:
    """A ``StreamDigest`` that digests nothing (the replay's contender without identity)."""

    def __init__(self, stored=None) -> None:
        self.stored = {}

    def add(self, x) -> None:
        pass

    def cut(self) -> None:
        pass

    def finish(self):
        from service.store.identity import StreamId

        return StreamId()

    def relate(self, new):
        return lambda source: None


def replay_contenders(seconds: float) -> None:
    """A healthy_noise log of ``seconds`` replayed (no store, no output) with the stream
    identity and with it replaced by a no-op; best of 3 each, after a warm-up."""
    import tempfile

    import service.replay.core as core
    from service.log import McapLogger
    from service.monitor.calibration import measured_run
    from service.replay import replay
    from service.sim.scenarios import load_scenario

    sc = load_scenario("healthy_noise").model_copy(update={"duration_s": seconds})
    meas = measured_run(sc)[1]
    names = [k for k in meas if k != "t"]
    vals = np.column_stack([meas["t"], *[meas[k] for k in names]])
    with tempfile.TemporaryDirectory() as d:
        log = Path(d) / "b.mcap"
        with McapLogger(log, background_flush=False) as lg:
            for i in range(0, len(vals), 1000):
                lg.log_block("/fleet/AC1/ail_L/meas", vals[i : i + 1000, 0], ("t", *names),
                             vals[i : i + 1000])  # fmt: skip
        replay(log)  # warm-up (JIT)
        real = core.StreamDigest
        t_with = _best(lambda: replay(log))
        core.StreamDigest = _NoIdentity
        try:
            t_without = _best(lambda: replay(log))
        finally:
            core.StreamDigest = real
    n = len(vals)
    print(f"replay of {n} samples ({seconds:g} s at 1 kHz), no store, no output log")
    print(f"{'contender':<34}{'wall s':>10}{'M samples/s':>14}")
    print(f"{'replay without the identity':<34}{t_without:>10.3f}{n / t_without / 1e6:>14.3f}")
    print(f"{'replay with the identity':<34}{t_with:>10.3f}{n / t_with / 1e6:>14.3f}")


if __name__ == "__main__":
    main()
