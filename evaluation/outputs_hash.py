"""Fingerprint of the monitor's outputs: one sha256 per bundled scenario over everything
``MonitorBank.update_arrays`` (the production path of the daemon and replay) returns.

    .venv/bin/python -m evaluation.outputs_hash            # about 1 min (the HF runs)
    .venv/bin/python -m evaluation.outputs_hash --json     # the hashes as one JSON object
    .venv/bin/python -m evaluation.outputs_hash --model C5 # another process model (default: WH)
    .venv/bin/python -m evaluation.outputs_hash --set adapt_nis=0   # a setting changed

``--fleet`` feeds the same blocks through a ``MonitorFleet`` (one bank per distinct baseline;
every actuator on the default here), which must give the same hashes as the plain bank.

Run it before and after a refactor that must not change behaviour: the hashes must be equal.
Each scenario's measured run (HF bench, seeded sensor noise, supply sensor on) is fed as three
actuators of one bank, in blocks of varying size: the run as measured; the run with the
pressure channels dropped every 7th sample, a NaN current every 11th and a 0.1 s gap at 1 s
(counters, re-initialisation); and the run with its time axis shifted by 1e-4 s. The hash
covers index, t, est, res and health (float64 bytes), every event (t, kind, state, value as
``float.hex``) and the final counters of each actuator.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from service.monitor import MonitorBank, MonitorConfig, MonitorFleet
from service.monitor.calibration import measured_run
from service.sim.scenarios import load_scenario
from service.wire.messages import CHANNELS

SCENARIOS = ("leak_step", "supply_drop", "combined", "healthy_noise")
BLOCKS = (1, 2, 3, 64, 250, 17, 500, 5)  # cycled: block sizes of the interleaved stream


def _streams(name: str, duration_s: float | None) -> list[tuple[np.ndarray, np.ndarray]]:
    sc = load_scenario(name)
    if duration_s is not None:
        sc = sc.model_copy(update={"duration_s": duration_s})
    _, meas = measured_run(sc, with_supply_sensor=True)
    t = np.asarray(meas["t"], float)
    ch = np.column_stack([np.asarray(meas[c], float) for c in CHANNELS])
    n = len(t)
    holey = ch.copy()
    j = np.arange(n)
    holey[j % 7 == 3, CHANNELS.index("p1")] = np.nan
    holey[j % 7 == 3, CHANNELS.index("p2")] = np.nan
    holey[j % 11 == 5, CHANNELS.index("i")] = np.nan
    keep = (t < 1.0) | (t >= 1.1)  # a gap longer than max_gap_s: re-initialisation
    return [(t, ch), (t[keep], holey[keep]), (t + 1e-4, ch)]


def scenario_hash(
    name: str,
    duration_s: float | None = None,
    fleet: bool = False,
    config: MonitorConfig | None = None,
) -> tuple[str, int]:
    """sha256 of the bank's outputs on scenario ``name`` (monitor ``config``, default
    ``MonitorConfig()``); also the number of blocks fed."""
    streams = _streams(name, duration_s)
    bank = MonitorFleet(config) if fleet else MonitorBank(config)
    ids = [bank.index_of(f"act{a}") for a in range(len(streams))]
    # interleave the actuators sample by sample, as a fleet's intake does
    ks = np.concatenate(
        [np.full(len(s[0]), k, np.int64) for k, s in zip(ids, streams, strict=True)]
    )
    ts = np.concatenate([s[0] for s in streams])
    chs = np.concatenate([s[1] for s in streams])
    pos = np.concatenate([np.arange(len(s[0])) for s in streams])
    order = np.lexsort((ks, pos))
    ks, ts, chs = ks[order], ts[order], chs[order]
    h = hashlib.sha256()
    a, n_blocks = 0, 0
    while a < len(ks):
        b = min(len(ks), a + BLOCKS[n_blocks % len(BLOCKS)])
        rows = bank.update_arrays(ks[a:b], ts[a:b], chs[a:b])
        for arr in (rows.index + a, rows.t, rows.est, rows.res, rows.health):
            h.update(np.ascontiguousarray(arr, np.float64).tobytes())
        for r in rows.events.rows():
            for ev in rows.events[r]:
                h.update(f"{r}|{ev.t.hex()}|{ev.kind}|{ev.state}|{float(ev.value).hex()}".encode())
        n_blocks += 1
        a = b
    for a in range(len(streams)):
        h.update(json.dumps(bank.counters_of(f"act{a}"), sort_keys=True).encode())
    return h.hexdigest(), n_blocks


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--duration-s", type=float, default=None, help="cut every scenario to this")
    ap.add_argument("--fleet", action="store_true", help="through a MonitorFleet")
    ap.add_argument("--model", default=None, help="process model (default: MonitorConfig's)")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a MonitorConfig setting (dotted for a group: alarms.leak_raise=3), repeatable",
    )
    args = ap.parse_args()
    cfg: dict = {} if args.model is None else {"model": args.model}
    for item in args.set:
        key, _, value = item.partition("=")
        *groups, leaf = key.split(".")
        d = cfg
        for g in groups:
            d = d.setdefault(g, {})
        d[leaf] = json.loads(value)
    config = MonitorConfig.model_validate(cfg)
    out = {}
    for name in SCENARIOS:
        digest, n_blocks = scenario_hash(name, args.duration_s, args.fleet, config)
        out[name] = digest
        if not args.json:
            print(f"{name:<14} {digest}  ({n_blocks} blocks)", flush=True)
    if args.json:
        print(json.dumps(out))


if __name__ == "__main__":
    main()
