"""Measurement message codecs: JSON vs the compact binary form (service.wire.messages).

For each format and batch size (samples per message) it measures, per sample: encode,
decode+validate (to MeasSample objects and to plain dicts), the pydantic schema validation for
comparison, and the bytes on the wire; then the CPU share that decoding takes at
1 kHz x 20 and x 50 actuators. Prints one table; ``--json`` prints one JSON object.

    .venv/bin/python bench/codec.py [--repeat 5] [--zenoh] [--json]

``--zenoh`` adds a transport run: a publisher process sends 20 or 50 actuators x 1 kHz
(10 samples per message) for 3 s through a router session that also subscribes and decodes;
it reports the CPU share of that process, samples received and whether the publisher kept
the pace.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.wire.messages import (  # noqa: E402
    MeasSample,
    decode_meas,
    decode_meas_arrays,
    decode_meas_dicts,
    encode_meas,
)


def _samples(n: int) -> list[MeasSample]:
    return [
        MeasSample(
            seq=1_000_000 + k,
            t=1.7e9 + k * 1e-3,
            x_cmd=5e-3 + 1e-3 * math.sin(k / 200),
            i=1.234567e-3 * math.cos(k / 50),
            x_s=2.345678e-5 * math.sin(k / 30),
            x_j=4.987654e-3 + 1e-5 * k,
            p1=1.2345678e7 + 123.4 * k,
            p2=7.654321e6 - 98.7 * k,
            p_sr=2.0e7 - 3.21 * k,
        )  # fmt: skip
        for k in range(n)
    ]


def _time(fn, n_samples: int, min_s: float = 0.2, repeat: int = 5) -> float:
    """Best-of-``repeat`` microseconds per sample."""
    best = math.inf
    for _ in range(repeat):
        k, t0 = 0, time.perf_counter()
        while True:
            fn()
            k += 1
            dt = time.perf_counter() - t0
            if dt >= min_s:
                break
        best = min(best, dt / (k * n_samples) * 1e6)
    return best


_PUBLISHER = """
import sys, time, zenoh
sys.path.insert(0, {root!r})
from service.wire.messages import encode_meas
from service.zenoh_util import make_config
acts, secs, fmt, per = {acts}, {secs}, {fmt!r}, {per}
s = zenoh.open(make_config("client", connect=[{ep!r}]))
pubs = [s.declare_publisher(f"fleet/AC{{a // 10:03d}}/act{{a % 10}}/meas") for a in range(acts)]
time.sleep(1.0)
n_msg = int(secs * 1000 / per)
t0 = time.perf_counter()
for k in range(n_msg):
    t = k * per * 1e-3
    rows = [dict(seq=k * per + j, t=t + j * 1e-3, x_cmd=0.005, i=1.2e-3 + j * 1e-6, x_s=2.1e-5,
                 x_j=4.9e-3 + j * 1e-7, p1=1.23e7 + j, p2=7.65e6 - j, p_sr=2e7) for j in range(per)]
    for a, p in enumerate(pubs):
        p.put(encode_meas(rows, fmt))
    due = t0 + (k + 1) * per * 1e-3
    while time.perf_counter() < due:
        time.sleep(0.0005)
print(time.perf_counter() - t0, flush=True)
time.sleep(0.5)
s.close()
"""


def zenoh_load(acts: int, fmt: str, secs: float = 3.0, per: int = 10) -> dict:
    """``acts`` actuators x 1 kHz (``per`` samples/message) from a publisher process through
    a router session that also subscribes and decodes; CPU of this process per traffic second."""
    import subprocess
    import threading

    import zenoh

    from service.zenoh_util import BoundedQueue, free_port, loopback, make_config

    ep = loopback(free_port())
    root = str(Path(__file__).resolve().parent.parent)
    q: BoundedQueue[bytes] = BoundedQueue(1_000_000)
    counts = {"samples": 0, "bad": 0}
    stop = threading.Event()

    def consume() -> None:
        while not stop.is_set() or len(q):
            for payload in q.get_batch(1000, timeout=0.05):
                try:
                    counts["samples"] += len(decode_meas_dicts(payload))
                except Exception:
                    counts["bad"] += 1

    with zenoh.open(make_config("router", listen=[ep])) as router:
        router.declare_subscriber("fleet/**/meas", lambda smp: q.put(smp.payload.to_bytes()))
        th = threading.Thread(target=consume, daemon=True)
        th.start()
        code = _PUBLISHER.format(root=root, acts=acts, secs=secs, fmt=fmt, per=per, ep=ep)
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
        time.sleep(1.0)  # publisher start-up (its own 1 s settle)
        c0, w0 = time.process_time(), time.perf_counter()
        out, _ = proc.communicate(timeout=secs * 10 + 30)
        stop.set()
        th.join(30)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    expected = acts * int(secs * 1000 / per) * per
    return {
        "actuators": acts, "format": fmt, "expected": expected, "received": counts["samples"],
        "bad": counts["bad"], "dropped_in_queue": q.dropped, "publish_wall_s": float(out or "nan"),
        "cpu_percent_of_one_core": 100 * cpu / secs, "wall_s": wall,
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    ap.add_argument(
        "--zenoh", action="store_true",
        help="also measure 20 and 50 actuators x 1 kHz through real Zenoh sessions",
    )  # fmt: skip
    args = ap.parse_args(argv)
    rows = []
    for n in (1, 10, 50):
        s = _samples(n)
        dumps = [x.model_dump() for x in s]
        for fmt in ("json", "bin"):
            payload = encode_meas(s, fmt)
            assert decode_meas(payload) == s
            enc = _time(lambda s=s, fmt=fmt: encode_meas(s, fmt), n, repeat=args.repeat)
            dec = _time(lambda p=payload: decode_meas(p), n, repeat=args.repeat)
            decd = _time(lambda p=payload: decode_meas_dicts(p), n, repeat=args.repeat)
            deca = _time(lambda p=payload: decode_meas_arrays(p), n, repeat=args.repeat)
            rows.append(
                {"format": fmt, "batch": n, "bytes_per_sample": len(payload) / n,
                 "encode_us": enc, "decode_validate_us": dec, "decode_dicts_us": decd,
                 "decode_arrays_us": deca}
            )  # fmt: skip
        pyd = _time(
            lambda d=dumps: [MeasSample.model_validate(x) for x in d], n, repeat=args.repeat
        )
        rows.append({"format": "pydantic model_validate (dict in)", "batch": n,
                     "decode_validate_us": pyd})  # fmt: skip
    out = {"rows": rows, "load": {}}
    for acts in (20, 50):
        rate = acts * 1000
        for r in rows:
            if r["format"] in ("json", "bin") and r["batch"] == 10:
                out["load"][f"{r['format']}_{acts}x1kHz_cpu_percent"] = (
                    rate * r["decode_dicts_us"] * 1e-6 * 100
                )
                out["load"][f"{r['format']}_{acts}x1kHz_MB_per_s"] = (
                    rate * r["bytes_per_sample"] / 1e6
                )
    if args.zenoh:
        out["zenoh"] = [zenoh_load(a, f) for a in (20, 50) for f in ("json", "bin")]
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"Measurement codec cost per sample (best of {args.repeat}; microseconds)")
    print(f"{'format':<36}{'batch':>6}{'B/sample':>10}{'encode':>9}{'decode+val':>12}"
          f"{'->dicts':>9}{'->arrays':>10}")  # fmt: skip
    for r in rows:
        bps = f"{r['bytes_per_sample']:.1f}" if "bytes_per_sample" in r else "-"
        enc = f"{r['encode_us']:.2f}" if "encode_us" in r else "-"
        dd = f"{r['decode_dicts_us']:.2f}" if "decode_dicts_us" in r else "-"
        da = f"{r['decode_arrays_us']:.2f}" if "decode_arrays_us" in r else "-"
        print(f"{r['format']:<36}{r['batch']:>6}{bps:>10}{enc:>9}"
              f"{r['decode_validate_us']:>12.2f}{dd:>9}{da:>10}")  # fmt: skip
    print("\nAt 10 samples per message, decoding to dicts (the daemon's former path):")
    for acts in (20, 50):
        for fmt in ("json", "bin"):
            cpu = out["load"][f"{fmt}_{acts}x1kHz_cpu_percent"]
            mb = out["load"][f"{fmt}_{acts}x1kHz_MB_per_s"]
            print(f"  {acts} actuators x 1 kHz, {fmt:<4}: {cpu:5.1f} % of one core, "
                  f"{mb:5.2f} MB/s on the wire")  # fmt: skip
    for z in out.get("zenoh", []):
        print(f"  Zenoh {z['actuators']} x 1 kHz {z['format']:<4} (router+subscriber+decode "
              f"process): {z['cpu_percent_of_one_core']:5.1f} % CPU, received "
              f"{z['received']}/{z['expected']} samples, bad {z['bad']}, "
              f"publisher took {z['publish_wall_s']:.2f} s for 3 s")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
