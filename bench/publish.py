"""The publish encode of est, res and health: JSON dicts (the code before decision 0018)
vs the protobuf rows (``service.wire.messages.encode_outputs``), per published output.

One bank update as the daemon makes it at 1 kHz with 10-sample messages (20 actuators x 10
samples: 200 output rows, 20 of them published at ``publish_every`` = 10). Per published
output (its est, res and health), best of ``--repeat`` runs:

* json: ``BankRows.output(r)`` then ``encode_json({"t": ..., **dict})`` x 3, as the fan-out
  did before;
* protobuf: the three leaves' messages of the update's published rows in a few array
  operations (``encode_output_rows``), cut into one ``bytes`` per put, as
  ``FanOut._publish`` does;

then the Zenoh ``put`` itself (router, publisher and a counting subscriber in this process,
loopback), per message of each form's sizes, and three rows in one put against three puts;
and ``FanOut.emit`` of this tree for the whole update (log selection, numbering, publish
encode; a recording logger and a session whose ``put`` does nothing), per sample.

    .venv/bin/python bench/publish.py [--repeat 7] [--no-zenoh] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
from codec import _time as best_us_per_sample  # noqa: E402  (bench/codec.py, beside this)

from service.daemon.fanout import FanOut  # noqa: E402
from service.monitor import MonitorBank  # noqa: E402
from service.monitor.calibration import measured_run  # noqa: E402
from service.sim.scenarios import load_scenario  # noqa: E402
from service.wire import messages as m  # noqa: E402

ACTUATORS, PER_MSG, PUBLISH_EVERY = 20, 10, 10


def _update():
    """(bank rows of one update, ks, published row indices)."""
    meas = measured_run(load_scenario("leak_step"))[1]
    n = 2000
    ch = np.column_stack([meas[c][:n] if c in meas else np.full(n, np.nan) for c in m.CHANNELS])
    bank = MonitorBank()
    ids = np.array([bank.index_of(f"AC{a:03d}/act") for a in range(ACTUATORS)])
    k0 = n - PER_MSG
    bank.update_arrays(np.repeat(ids, k0), np.tile(meas["t"][:k0], ACTUATORS),
                       np.tile(ch[:k0], (ACTUATORS, 1)))  # fmt: skip
    ks = np.repeat(ids, PER_MSG)
    rows = bank.update_arrays(
        ks, np.tile(meas["t"][k0:n], ACTUATORS), np.tile(ch[k0:], (ACTUATORS, 1))
    )
    pub = np.flatnonzero(np.arange(len(rows.t)) % PER_MSG == PER_MSG - 1)
    return rows, ks, pub


def _best_us(fn, per: int, repeat: int) -> float:
    """Best-of-``repeat`` microseconds per item (``fn`` does ``per`` items)."""
    return best_us_per_sample(fn, per, repeat=repeat)


def encode_json_rows(rows, pub) -> list[bytes]:
    """The JSON era's publish encode (``FanOut._publish`` before 0018)."""
    out = []
    rows._lists, rows._n_out = None, 0  # a fresh update, as the daemon's
    for r in pub.tolist():
        o = rows.output(r)
        health = {**o.health, "commissioned": True, "baseline_version": 1}
        for d in (o.est, o.res, health):
            out.append(m.encode_json({"t": o.t, **d}))
    return out


def encode_proto_rows(rows, pub) -> list[bytes]:
    """The protobuf publish encode (``FanOut._publish``): est, res, health of each row."""
    info = np.ones((len(pub), 2), np.int64)
    buf, sizes = m.encode_output_rows(rows.est[pub], rows.res[pub], rows.health[pub],
                                      rows.t[pub], info)  # fmt: skip
    out, off = [], 0
    for _ in range(len(pub)):
        for size in sizes:
            out.append(buf[off : off + size])
            off += size
    return out


class _NullPub:
    def put(self, payload: bytes) -> None:
        pass


class _NullSession:
    def declare_publisher(self, key: str, **kw) -> _NullPub:
        return _NullPub()


class _Logger:
    def log(self, *a) -> None:
        pass

    def log_blocks(self, *a) -> None:
        pass


def _emit_us(rows, ks, repeat: int) -> float:
    fo = FanOut(_Logger(), log_every=1, publish_every=PUBLISH_EVERY, session=_NullSession())
    for k in np.unique(ks).tolist():
        fo.track(k, f"AC{k:03d}", "act", info={"commissioned": True, "baseline_version": 1})
    return _best_us(lambda: fo.emit(rows, ks), len(rows.t), repeat)


def _zenoh_puts(sizes: dict[str, int], repeat: int) -> dict[str, float]:
    """Microseconds per put of a payload of each size (a router, a publisher and a
    subscriber that counts, on loopback)."""
    import zenoh

    from service.zenoh_util import free_port, loopback, make_config

    port = free_port()
    got = [0]
    out = {}
    with (
        zenoh.open(make_config("router", listen=[loopback(port)])),
        zenoh.open(make_config("client", connect=[loopback(port)])) as sub_s,
        zenoh.open(make_config("client", connect=[loopback(port)])) as pub_s,
    ):
        sub = sub_s.declare_subscriber("bench/**", lambda s: got.__setitem__(0, got[0] + 1))
        time.sleep(0.5)
        for name, size in sizes.items():
            p = pub_s.declare_publisher(f"bench/{name}")
            payload = bytes(size)
            out[name] = _best_us(lambda p=p, payload=payload: [p.put(payload) for _ in range(100)],
                                 100, repeat)  # fmt: skip
            p.undeclare()
        sub.undeclare()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--no-zenoh", action="store_true")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows, ks, pub = _update()
    js, pb = encode_json_rows(rows, pub), encode_proto_rows(rows, pub)
    for i, leaf in enumerate(("est", "res", "health")):  # the same numbers in both forms
        for k in range(len(pub)):
            assert m.decode_output(leaf, pb[3 * k + i]) == json.loads(js[3 * k + i])
    res = {
        "load_avg_1m": os.getloadavg()[0],
        "published_per_update": len(pub),
        "encode_us_per_output": {
            "json": _best_us(lambda: encode_json_rows(rows, pub), len(pub), args.repeat),
            "protobuf": _best_us(lambda: encode_proto_rows(rows, pub), len(pub), args.repeat),
        },
        "bytes_per_output": {
            "json": sum(map(len, js)) / len(pub),
            "protobuf": sum(map(len, pb)) / len(pub),
        },  # fmt: skip
        "emit_us_per_sample": _emit_us(rows, ks, args.repeat),
    }
    if not args.no_zenoh:
        sz = {f"json_{leaf}": len(js[i]) for i, leaf in enumerate(("est", "res", "health"))}
        sz |= {f"protobuf_{leaf}": len(pb[i]) for i, leaf in enumerate(("est", "res", "health"))}
        sz["protobuf_3_rows_one_put"] = sum(len(pb[i]) for i in range(3))
        res["put_us"] = _zenoh_puts(sz, args.repeat)
    if args.json:
        print(json.dumps(res))
        return 0
    e, b = res["encode_us_per_output"], res["bytes_per_output"]
    print(f"load average (1 min) {res['load_avg_1m']:.2f}; one update of {ACTUATORS} actuators "
          f"x {PER_MSG} samples, {len(pub)} outputs published")  # fmt: skip
    print(f"{'per published output (est+res+health)':40s} {'json':>10s} {'protobuf':>10s}")
    print(f"{'encode us':40s} {e['json']:10.2f} {e['protobuf']:10.2f}")
    print(f"{'bytes':40s} {b['json']:10.0f} {b['protobuf']:10.0f}")
    if "put_us" in res:
        p = res["put_us"]
        puts_j = sum(p[f"json_{x}"] for x in ("est", "res", "health"))
        puts_p = sum(p[f"protobuf_{x}"] for x in ("est", "res", "health"))
        print(f"{'3 Zenoh puts us':40s} {puts_j:10.2f} {puts_p:10.2f}")
        print(
            f"{'encode + 3 puts us':40s} {e['json'] + puts_j:10.2f} {e['protobuf'] + puts_p:10.2f}"
        )
        print(f"one put of the 3 protobuf rows: {p['protobuf_3_rows_one_put']:.2f} us "
              f"(3 puts: {puts_p:.2f} us)")  # fmt: skip
    print(f"FanOut.emit of this tree, whole update: {res['emit_us_per_sample']:.2f} us per sample")
    return 0


if __name__ == "__main__":
    sys.exit(main())
