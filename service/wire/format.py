"""The binary ``meas`` wire format's constants, shared by the Python decoder
(``service.wire.messages``) and its compiled part (``service.wire.kernels``) without either
importing the other at import time (docs/messages.md, "JSON or binary: the measurement")."""

from __future__ import annotations

from models.channels import SENSORS

#: Measured channels in wire order (SI: m, A, m, m, Pa abs, Pa abs, Pa).
CHANNELS: tuple[str, ...] = SENSORS

#: bytes of one binary record, and the status of a message after ``messages.decode_into``:
#: decoded and accepted whole by the intake's compiled checks, decoded only, not decoded
REC_BYTES = 73
BATCH_ACCEPTED, BATCH_DECODED, BATCH_UNDECODED = 0, 1, 2
