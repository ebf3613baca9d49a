"""Building already-validated ``MeasSample`` objects: pydantic's public ``model_construct``
against the hand-written construction in ``service.wire.messages`` (which writes pydantic's
instance slots itself), side by side in one run.

    .venv/bin/python research/pydantic_construct.py [--rounds 15] [--n 20000] [--json]

Rows, microseconds per object (median over ``--rounds`` interleaved rounds of ``--n``
objects each; ratio = median of the per-round ratios to the first row):

* ``hand``: ``service.wire.messages._make``, through ``service.compat.pydantic.construct_unchecked``
  (object.__new__ and pydantic's four instance slots written by hand);
* ``hand inline``: the same slot writes inlined in one function (the code before the
  fence), which shows the cost of the extra call;
* ``model_construct``: ``MeasSample.model_construct(**fields)``;
* ``model_construct fields_set``: the same with ``_fields_set`` given (no set computed);
* ``validated``: ``MeasSample(**fields)``, full validation, for scale;
* ``decode 10/msg``: ``decode_meas`` of a binary message of 10 samples, per sample, which
  is where the construction runs (the ``hand`` path).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.wire import messages as msg  # noqa: E402
from service.wire.messages import CHANNELS, MeasSample, decode_meas, encode_meas  # noqa: E402


def _rows(n: int) -> list[tuple[int, float, list[float | None]]]:
    return [
        (k, 1.7e9 + k * 1e-3, [1e-3 * k, 2e-3, 1e-5, 2e-2, 1.1e7, 1.0e7 if k % 3 else None, 2e7])
        for k in range(n)
    ]


def _variants(rows):
    keys = ("seq", "t", *CHANNELS)
    dicts = [dict(zip(keys, (s, t, *v), strict=True)) for s, t, v in rows]
    fs = set(keys)
    mc = MeasSample.model_construct
    make = msg._make
    blob = encode_meas(dicts[:10])

    def hand():
        for s, t, v in rows:
            make(s, t, v)

    def hand_inline():
        new, setattr_ = object.__new__, object.__setattr__
        for s, t, v in rows:
            d = {"seq": s, "t": t}
            d.update(zip(CHANNELS, v, strict=True))
            m = new(MeasSample)
            setattr_(m, "__dict__", d)
            setattr_(m, "__pydantic_fields_set__", set(d))
            setattr_(m, "__pydantic_extra__", None)
            setattr_(m, "__pydantic_private__", None)

    def construct():
        for d in dicts:
            mc(**d)

    def construct_fs():
        for d in dicts:
            mc(fs, **d)

    def validated():
        for d in dicts:
            MeasSample(**d)

    def decode():
        for _ in range(len(rows) // 10):
            decode_meas(blob)

    return {
        "hand": hand,
        "hand inline": hand_inline,
        "model_construct": construct,
        "model_construct fields_set": construct_fs,
        "validated": validated,
        "decode 10/msg": decode,
    }


def _same(rows) -> bool:
    """model_construct and the hand path give equal objects (fields, fields_set, dump)."""
    keys = ("seq", "t", *CHANNELS)
    for s, t, v in rows[:100]:
        a = msg._make(s, t, v)
        b = MeasSample.model_construct(**dict(zip(keys, (s, t, *v), strict=True)))
        if a != b or a.model_fields_set != b.model_fields_set or a.model_dump() != b.model_dump():
            return False
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--n", type=int, default=20000)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = _rows(args.n)
    fns = _variants(rows)
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(args.rounds):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[name].append((time.perf_counter() - t0) / args.n * 1e6)
    base = times["hand"]
    out = {
        name: {
            "us_per_object": statistics.median(ts),
            "best_us": min(ts),
            "ratio_to_hand": statistics.median(a / b for a, b in zip(ts, base, strict=True)),
        }
        for name, ts in times.items()
    }
    same = _same(rows)
    if args.json:
        print(json.dumps({"rows": out, "equal_objects": same}))
        return
    print(f"{'construction':<28} {'median us':>10} {'best us':>9} {'x hand':>7}")
    for name, r in out.items():
        print(
            f"{name:<28} {r['us_per_object']:>10.3f} {r['best_us']:>9.3f} "
            f"{r['ratio_to_hand']:>7.2f}"
        )
    print(f"model_construct equals the hand path: {same}")


if __name__ == "__main__":
    main()
