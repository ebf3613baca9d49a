"""Measurement message codecs: JSON vs the compact binary form (service.messages).

For each format and batch size (samples per message) it measures, per sample: encode,
decode+validate (to MeasSample objects and to plain dicts), the pydantic schema validation for
comparison, and the bytes on the wire; then the CPU share that decoding takes at
1 kHz x 20 and x 50 actuators. Prints one table; ``--json`` prints one JSON object.

    .venv/bin/python bench/codec.py [--repeat 5] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.messages import MeasSample, decode_meas, decode_meas_dicts, encode_meas  # noqa: E402


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true")
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
            rows.append(
                {"format": fmt, "batch": n, "bytes_per_sample": len(payload) / n,
                 "encode_us": enc, "decode_validate_us": dec, "decode_dicts_us": decd}
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
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"Measurement codec cost per sample (best of {args.repeat}; microseconds)")
    print(f"{'format':<36}{'batch':>6}{'B/sample':>10}{'encode':>9}{'decode+val':>12}"
          f"{'->dicts':>9}")  # fmt: skip
    for r in rows:
        bps = f"{r['bytes_per_sample']:.1f}" if "bytes_per_sample" in r else "-"
        enc = f"{r['encode_us']:.2f}" if "encode_us" in r else "-"
        dd = f"{r['decode_dicts_us']:.2f}" if "decode_dicts_us" in r else "-"
        print(f"{r['format']:<36}{r['batch']:>6}{bps:>10}{enc:>9}"
              f"{r['decode_validate_us']:>12.2f}{dd:>9}")  # fmt: skip
    print("\nAt 10 samples per message, decoding to dicts (what the daemon does):")
    for acts in (20, 50):
        for fmt in ("json", "bin"):
            cpu = out["load"][f"{fmt}_{acts}x1kHz_cpu_percent"]
            mb = out["load"][f"{fmt}_{acts}x1kHz_MB_per_s"]
            print(f"  {acts} actuators x 1 kHz, {fmt:<4}: {cpu:5.1f} % of one core, "
                  f"{mb:5.2f} MB/s on the wire")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
