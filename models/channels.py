"""The actuator's instrumented channels, in the order every sample carries them (the wire,
the logs, the monitor's input columns): command x_cmd [m], valve current i [A], spool x_s [m],
ram x_j [m], chamber pressures p1, p2 [Pa abs], supply p_sr [Pa] (docs/messages.md)."""

from __future__ import annotations

SENSORS: tuple[str, ...] = ("x_cmd", "i", "x_s", "x_j", "p1", "p2", "p_sr")
