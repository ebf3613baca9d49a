"""A Zenoh client of one role for the security tests, run in its own process.

Its session comes from ``service.config.load_config`` (the ``SERVOWATCH_ZENOH__*`` variables
the test sets: the endpoint and this role's TLS files), so it joins exactly as a servowatch
command does. Prints one JSON object on stdout.

    python tests/_zenoh_role.py put KEY TEXT COUNT     # COUNT puts, 20 ms apart
    python tests/_zenoh_role.py get KEY TEXT           # one query; how many replies
    python tests/_zenoh_role.py listen KEYEXPR MARK    # until SIGTERM: samples per key
    python tests/_zenoh_role.py token KEY [KEY ...]    # until SIGTERM: hold liveliness tokens
    python tests/_zenoh_role.py serve KEY [KEY ...]    # until SIGTERM: queryables; queries got
    python tests/_zenoh_role.py answer KEY TEXT        # until SIGTERM: a queryable answering TEXT

``{zid}`` in a token key is replaced by the session id.
"""

from __future__ import annotations

import collections
import json
import signal
import sys
import threading
import time


def main(argv: list[str]) -> int:
    from service.config import SessionError, load_config

    try:
        session = load_config(None).zenoh.open_session()
    except SessionError as e:
        print(json.dumps({"opened": False, "error": str(e)}))
        return e.exit_code
    out: dict = {"opened": True}
    with session:
        if argv[0] == "put":
            key, text, n = argv[1], argv[2], int(argv[3])
            time.sleep(0.5)  # let the declarations settle
            for _ in range(n):
                session.put(key, text.encode())
                time.sleep(0.02)
            out["sent"] = n
        elif argv[0] == "get":
            replies = list(session.get(argv[1], payload=argv[2].encode(), timeout=2.0))
            out["replies"] = sum(r.ok is not None for r in replies)
        elif argv[0] in ("token", "serve"):
            zid = str(session.info.zid())
            stop = threading.Event()
            signal.signal(signal.SIGTERM, lambda *_: stop.set())
            got: collections.Counter = collections.Counter()

            def on_query(q) -> None:
                got[str(q.key_expr)] += 1
                q.reply(q.key_expr, b"{}")

            decl = [
                session.liveliness().declare_token(k.replace("{zid}", zid))
                if argv[0] == "token"
                else session.declare_queryable(k, on_query)
                for k in argv[1:]
            ]
            print(json.dumps({"ready": True}), flush=True)
            stop.wait()
            for d in decl:
                d.undeclare()
            out["queries"] = dict(got)
        elif argv[0] == "answer":
            text = argv[2].encode()
            stop = threading.Event()
            signal.signal(signal.SIGTERM, lambda *_: stop.set())
            q = session.declare_queryable(argv[1], lambda qq: qq.reply(argv[1], text))
            print(json.dumps({"ready": True}), flush=True)
            stop.wait()
            q.undeclare()
        elif argv[0] == "listen":
            mark = argv[2].encode()
            counts: collections.Counter = collections.Counter()
            marked: collections.Counter = collections.Counter()
            lock = threading.Lock()

            def on_sample(s) -> None:
                key = str(s.key_expr)
                with lock:
                    counts[key] += 1
                    if mark in s.payload.to_bytes():
                        marked[key] += 1

            stop = threading.Event()
            signal.signal(signal.SIGTERM, lambda *_: stop.set())
            sub = session.declare_subscriber(argv[1], on_sample)
            print(json.dumps({"ready": True}), flush=True)
            stop.wait()
            sub.undeclare()
            with lock:
                out["counts"], out["marked"] = dict(counts), dict(marked)
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
