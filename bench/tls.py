"""Benchmark: the cost of mutual TLS and access control, beside plain TCP, side by side.

Runs ``bench/service.py``'s own run (its load generator, its daemon, its router: imported,
not copied) alternately over a plain ``tcp/127.0.0.1`` link and over the secure station's
link: ``tls/127.0.0.1`` with mutual TLS, the router loaded from ``deploy/secure/router.json5``
(access control on, default deny) plus one rule for the generator's identity (``acq-bench``:
put ``fleet/*/*/meas``; its aircraft are AC000..). The PKI is made by
``deploy/pki/make-certs.sh`` in a temporary directory. Every process of a TLS run (router,
generator, daemon) gets the TLS settings through ``SERVOWATCH_BENCH_TLS`` (the PKI directory),
read only by this script.

    .venv/bin/python bench/tls.py --actuators 20 --rate 1000 --duration 10 --repeat 2

The TLS cost is reported on the sample-age p50 (sample time -> health output, which includes
the transport; the daemon's receipt -> health latency does not) and on the daemon's busy
fraction; target: under 15 % at 20 actuators x 1 kHz.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
_ENV = "SERVOWATCH_BENCH_TLS"


def _bench_service():
    """bench/service.py as a module (its file name shadows the ``service`` package)."""
    spec = importlib.util.spec_from_file_location("bench_service", ROOT / "bench" / "service.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _secure(pki: Path, identity: str) -> None:
    """Make this process's Zenoh links mutual TLS as ``identity`` (router: the station ACL)."""
    import zenoh

    import service.config as config
    import service.zenoh_util as zu

    make = zu.make_config

    def make_config(mode="peer", listen=(), connect=(), *, allow_remote=False, extra=None):
        tls = config.TlsSettings(
            root_ca=pki / "ca.pem", cert=pki / f"{identity}.pem", key=pki / f"{identity}.key"
        )
        cfg = make(mode, listen, connect, allow_remote=allow_remote,
                   extra={**tls.to_zenoh(listen=bool(listen)), **(extra or {})})  # fmt: skip
        if mode == "router":
            acl = json.loads(
                zenoh.Config.from_file(str(ROOT / "deploy/secure/router.json5")).get_json(
                    "access_control"
                )
            )
            acl["rules"].append(
                {
                    "id": "acq-bench",
                    "permission": "allow",
                    "flows": ["ingress"],
                    "messages": ["put"],
                    "key_exprs": ["fleet/*/*/meas"],
                }
            )
            acl["rules"].append({"id": "acq-bench-out", "permission": "allow",
                                 "flows": ["egress"], "messages": ["declare_subscriber"],
                                 "key_exprs": ["fleet/**"]})  # fmt: skip
            acl["subjects"].append({"id": "acq-bench", "cert_common_names": ["acq-bench"]})
            acl["policies"].append(
                {"id": "acq-bench", "rules": ["acq-bench", "acq-bench-out"],
                 "subjects": ["acq-bench"]}
            )  # fmt: skip
            cfg.insert_json5("access_control", json.dumps(acl))
        return cfg

    class Zenoh(config.ZenohSettings):
        tls: config.TlsSettings = config.TlsSettings(
            root_ca=pki / "ca.pem", cert=pki / f"{identity}.pem", key=pki / f"{identity}.key"
        )

    zu.make_config = make_config
    zu.loopback = lambda port: f"tls/127.0.0.1:{int(port)}"
    config.make_config = make_config
    config.ZenohSettings = Zenoh


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    bs = _bench_service()
    if argv and argv[0] in ("_gen", "_daemon"):  # a child of bench/service.py's run_one
        if os.environ.get(_ENV):
            _secure(Path(os.environ[_ENV]), "acq-bench" if argv[0] == "_gen" else "monitor")
        return bs.main(argv)
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--actuators", type=int, default=20)
    p.add_argument("--rate", type=float, default=1000.0)
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--monitor", choices=("real", "null"), default="real")
    p.add_argument("--repeat", type=int, default=2, help="TCP/TLS pairs, interleaved")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    bs.__file__ = __file__  # run_one starts its children from this file (above)
    rows = []
    with tempfile.TemporaryDirectory(prefix="servowatch-tls-") as tmp:
        pki = Path(tmp) / "pki"
        subprocess.run(
            ["bash", str(ROOT / "deploy/pki/make-certs.sh"), str(pki), "router", "monitor",
             "acq-bench"], check=True, capture_output=True,
        )  # fmt: skip
        for k in range(args.repeat):
            for link in ("tcp", "tls"):
                print(f"run {k + 1}/{args.repeat}: {link}", file=sys.stderr, flush=True)
                if link == "tls":
                    os.environ[_ENV] = str(pki)
                    _secure(pki, "router")
                else:
                    os.environ.pop(_ENV, None)
                    bs = _bench_service()  # unpatched helpers for the plain run
                    bs.__file__ = __file__
                    import importlib

                    import service.config
                    import service.zenoh_util

                    importlib.reload(service.zenoh_util)
                    importlib.reload(service.config)
                row = bs.run_one(args.actuators, args.rate, args.duration, args.monitor)
                row["link"] = link
                print("  " + json.dumps(row), file=sys.stderr, flush=True)
                rows.append(row)
    print(
        f"servowatch daemon over TCP and over mutual TLS + access control ({os.cpu_count()} CPUs)"
    )
    print(f"{'link':>5} {'act x Hz':>10} {'sent':>8} {'accepted':>8} {'dropped':>7} "
          f"{'age p50':>8} {'age p99':>8} {'lat p50':>8} {'lat p99':>8} {'busy':>5} {'keeps up':>8}")  # fmt: skip
    for r in rows:
        print(
            f"{r['link']:>5} {r['actuators']:>4} x {r['rate_hz']:<4g} {r['sent']:>8} "
            f"{r['accepted']:>8} {r['dropped']:>7} {bs._f(r['age_p50_ms']):>8} "
            f"{bs._f(r['age_p99_ms']):>8} {bs._f(r['lat_p50_ms']):>8} "
            f"{bs._f(r['lat_p99_ms']):>8} {r['busy']:>5.2f} {'yes' if r['keeps_up'] else 'NO':>8}"
        )

    def med(link: str, key: str) -> float:
        return statistics.median(r[key] for r in rows if r["link"] == link and r[key] is not None)

    for key in ("age_p50_ms", "busy"):
        tcp, tls = med("tcp", key), med("tls", key)
        print(f"TLS cost on {key} (median of the runs): {tcp:.3g} -> {tls:.3g} "
              f"({100 * (tls - tcp) / tcp:+.1f} %)")  # fmt: skip
    if args.json:
        print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
