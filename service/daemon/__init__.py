"""The monitoring daemon as a pipeline (docs/design.md, "The daemon's pipeline"): ``intake``
(the receive queue, per-actuator state and the acceptance checks), ``monitoring`` (the monitor
stage), ``outputs`` (log, fan-out, store, live feed), one ``block.Block`` per tick between
them; ``member`` and ``group`` (monitor groups), ``commission`` (auto-commissioning),
``status`` (the snapshot), ``systemd`` (sd_notify, watchdog), ``ratelimit``; ``core`` (the
:class:`Daemon`: Zenoh entities, the worker, start/stop). ``fanout``: the output
fan-out, shared with the replay.
May import every layer below it (config, edge, sim, prognostics, wire, monitor, log, store);
never replay or cli.
"""

from service.daemon.core import EXIT_LOG_FAILURE, Daemon, default_log_path
from service.daemon.intake import MAX_ACTUATORS, ActuatorState
from service.daemon.ratelimit import RateLimitedLog
from service.daemon.status import percentiles
from service.daemon.systemd import extending_start, notify_ready, sd_notify, watchdog_interval

__all__ = [
    "ActuatorState",
    "Daemon",
    "EXIT_LOG_FAILURE",
    "MAX_ACTUATORS",
    "RateLimitedLog",
    "default_log_path",
    "extending_start",
    "notify_ready",
    "percentiles",
    "sd_notify",
    "watchdog_interval",
]
