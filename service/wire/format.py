"""The binary ``meas`` wire format's constants, shared by the Python decoder
(``service.messages``) and its compiled part (``service.wire_kernels``) without either
importing the other at import time (docs/messages.md, "JSON or binary: the measurement")."""

from __future__ import annotations

#: Measured channels in wire order (SI: m, A, m, m, Pa abs, Pa abs, Pa).
CHANNELS: tuple[str, ...] = ("x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr")

#: bytes of one binary record, and the status of a message after ``messages.decode_into``:
#: decoded and accepted whole by the intake's compiled checks, decoded only, not decoded
REC_BYTES = 73
BATCH_ACCEPTED, BATCH_DECODED, BATCH_UNDECODED = 0, 1, 2
