"""``servowatch inject``: send a fault command to a virtual actuator and print its answer."""

from __future__ import annotations

import argparse
import sys

from service.cli.util import emit_json, fail, finite_float

NAME = "inject"
HELP = "Inject a fault into a virtual actuator (leak, supply, sensor_bias, dropout, clear)."


def add_arguments(p: argparse.ArgumentParser) -> None:
    from service.cli.args import add_zenoh_arguments

    p.add_argument("--aircraft", default="AC001")
    p.add_argument("--actuator", default="elevator_L")
    p.add_argument(
        "--fault",
        required=True,
        choices=("leak", "supply", "sensor_bias", "dropout", "clear"),
        help="leak: c_lk [m^3/s/Pa]; supply: P_SR [Pa]; sensor_bias: SI bias on "
        "--channel; dropout: --channel missing (none = whole actuator); clear",
    )
    p.add_argument("--value", type=finite_float, default=None, help="fault value (SI)")
    p.add_argument("--ramp-s", type=finite_float, default=0.0, help="ramp time [s] (0 = step)")
    p.add_argument("--channel", default=None, help="sensor channel (i, x_s, x_j, p1, p2, p_sr)")
    p.add_argument(
        "--duration-s",
        type=finite_float,
        default=None,
        help="the fault clears itself after this long [s]",
    )
    p.add_argument("--timeout", type=float, default=10.0, help="reply timeout [s]")
    p.add_argument("--json", action="store_true", help="print the acknowledgement as JSON")
    add_zenoh_arguments(p)


def is_virtual(session, aircraft: str, actuator: str, timeout: float = 3.0) -> bool:
    """True if a virtual actuator holds its ``fleet/{ac}/{act}/@virtual`` liveliness token."""
    from service.wire import messages as msgs

    vkey = msgs.key(msgs.KEY_VIRTUAL, aircraft=aircraft, actuator=actuator)
    return any(r.ok is not None for r in session.liveliness().get(vkey, timeout=timeout))


def send_fault(session, aircraft: str, actuator: str, command, timeout: float = 3.0):
    """Send a ``FaultCommand``; return the ``FaultAck`` or None if nobody answered.

    Fault commands go to virtual actuators only: a key whose ``@virtual`` liveliness token is
    not visible (a real aircraft's acquisition, an absent actuator, or an identity the router
    does not let see it) gets a refusal without any command being sent.
    """
    from service.wire import messages as msgs

    key = msgs.key(msgs.KEY_FAULT, aircraft=aircraft, actuator=actuator)
    if not is_virtual(session, aircraft, actuator, timeout):
        vkey = msgs.key(msgs.KEY_VIRTUAL, aircraft=aircraft, actuator=actuator)
        return msgs.FaultAck(
            ok=False,
            message=f"refused: {aircraft}/{actuator} is not a virtual actuator reachable by "
            f"this identity (no {vkey} token); no command sent",
            active=[],
        )
    for reply in session.get(key, payload=command.model_dump_json().encode(), timeout=timeout):
        if reply.ok is not None:
            return msgs.FaultAck.model_validate_json(reply.ok.payload.to_bytes())
    return None


_UNITS = {"leak": "m^3/(s Pa)", "supply": "Pa"}


def _when(t) -> str:
    """A fault's end: RFC 3339 for a calendar (Unix) time, seconds for a simulated one."""
    from service.log.retention import rfc3339

    if not isinstance(t, int | float) or isinstance(t, bool):
        return "until cleared"
    return f"until {rfc3339(t)}" if t > 1e8 else f"until t = {t:g} s"


def format_fault(f: dict) -> str:
    """One active fault of a ``FaultAck`` as a line: ``leak 6.1e-13 m^3/(s Pa), ramping to
    8e-13, until cleared``; ``dropout of p1 until 2026-12-04T09:53:20.536Z``."""
    kind = str(f.get("kind"))
    parts = [kind]
    if "channel" in f:
        parts.append(f"of {f['channel']}" if kind == "dropout" else f"on {f['channel']}")
    v, target = f.get("value"), f.get("target")
    if isinstance(v, int | float):
        parts.append(f"{v:.3g}" + (f" {_UNITS[kind]}" if kind in _UNITS else ""))
    text = " ".join(parts)
    if isinstance(target, int | float) and isinstance(v, int | float) and target != v:
        text += f", ramping to {target:.3g}"
    return f"{text}, {_when(f.get('until'))}"


def run(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from service.cli.args import open_zenoh_session, zenoh_config
    from service.wire import messages as msgs

    try:
        cmd = msgs.FaultCommand(
            kind=args.fault,
            value=args.value,
            ramp_s=args.ramp_s,
            channel=args.channel,
            duration_s=args.duration_s,
        )
        msgs.key(msgs.KEY_FAULT, aircraft=args.aircraft, actuator=args.actuator)
    except ValidationError as e:
        err = e.errors()[0]
        return fail(f"invalid fault command: {'.'.join(map(str, err['loc']))}: {err['msg']}")
    except (msgs.MessageError, ValueError) as e:
        return fail(str(e))
    with open_zenoh_session(zenoh_config(args)) as session:
        ack = send_fault(session, args.aircraft, args.actuator, cmd, args.timeout)
    if ack is None:
        return fail(
            f"no answer from {args.aircraft}/{args.actuator} within {args.timeout} s "
            "(is the actuator running and reachable?)",
            3,
        )
    if args.json:
        emit_json(ack.model_dump())
    else:
        print(("ok: " if ack.ok else "") + ack.message)
        for f in ack.active:
            print("  active:", format_fault(f))
    if not ack.ok:
        print(f"servowatch: {ack.message}", file=sys.stderr)
    return 0 if ack.ok else 1
