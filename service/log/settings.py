"""``[log]``: the retention of the daemon's MCAP logs (``service.log.retention``, decision
0041). Part of ``ServiceConfig``; environment: ``SERVOWATCH_LOG__KEEP_BYTES`` ..."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["LogSettings", "DEFAULT_KEEP_BYTES", "DEFAULT_KEEP_DAYS"]

#: the default limits: 50 GiB of one daemon's logs, 30 days (one actuator at log_every = 1
#: writes about 1.6 GB an hour: docs/messages.md, "Volume and retention")
DEFAULT_KEEP_BYTES = 50 * 2**30
DEFAULT_KEEP_DAYS = 30.0


class LogSettings(BaseModel):
    """How much of its MCAP logs a daemon keeps: the oldest closed files beyond either limit
    are deleted (never the open file, never a file being read or ingested). ``null``: no
    limit of that kind."""

    model_config = ConfigDict(extra="forbid")

    keep_bytes: int | None = Field(
        DEFAULT_KEEP_BYTES, gt=0, description="keep at most this many bytes of logs [bytes]"
    )
    keep_days: float | None = Field(
        DEFAULT_KEEP_DAYS, gt=0, description="delete logs that ended longer ago than this [days]"
    )
    sweep_s: float = Field(
        60.0, gt=0, le=86400, description="check the limits this often (and at each rotation) [s]"
    )
