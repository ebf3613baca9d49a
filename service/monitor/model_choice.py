"""The monitor's process models and the default one, importable without numpy or numba (the
command-line parsers use them; ``service.monitor.config`` checks them against the models)."""

from __future__ import annotations

__all__ = ["MONITOR_MODELS", "DEFAULT_MODEL"]

MONITOR_MODELS: tuple[str, ...] = ("A", "B", "C1", "C3", "C5", "WH")
"""Process models of the monitor: the C-type laws of ``models.valve_laws`` (A, B, C1, C3, C5;
``models.eha_reduced``) and WH (``models.eha_reduced_wh``, the C-type parameters plus the two
chamber pressures; docs/models.md)."""

DEFAULT_MODEL = "WH"
"""The monitor's process model unless one is chosen (every command, the daemon's config)."""
