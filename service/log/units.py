"""The unit of every field the log and the published outputs carry (SI; ``1``: a number
without unit), for the schemas' field comments and the channels' metadata (issue 54).

One table by field name: the measured channels, the estimated states, their 1-sigma and the
residuals (``innov_X``, ``ol_X``: the unit of X) share their quantity's unit."""

from __future__ import annotations

__all__ = ["UNITS", "unit_of", "units_of"]

UNITS: dict[str, str] = {
    # measurement (docs/messages.md, "Measurement sample schema")
    "t": "s (Unix time)",
    "seq": "1 (sequence number)",
    "x_cmd": "m (commanded jack position)",
    "i": "A (servovalve current)",
    "x_s": "m (spool position)",
    "x_j": "m (jack position)",
    "p1": "Pa (chamber 1 pressure, absolute)",
    "p2": "Pa (chamber 2 pressure, absolute)",
    "p_sr": "Pa (supply pressure, absolute)",
    # estimated states
    "v_s": "m/s (spool velocity)",
    "v_j": "m/s (jack velocity)",
    "f_r": "N (external load)",
    "c_lk": "m^3/(s Pa) (internal leakage coefficient)",
    "i_b": "A (servovalve null bias)",
    "p12": "Pa (load pressure P1 - P2)",
    "c_lk_increase": "m^3/(s Pa) (C_Lk above its baseline)",
    # residuals
    "nis": "1 (normalised innovation squared)",
    "nis_dof": "1 (measurements in the NIS)",
    # health
    "leak_ratio": "1 (C_Lk over the baseline's)",
    "supply_ratio": "1 (P_SR over the baseline's)",
    "alarm_leak": "1 (0 or 1)",
    "alarm_supply": "1 (0 or 1)",
    "nis_avg": "1 (NIS per measurement, averaged)",
    # events
    "kind": "text (leak, supply, nis, silent, resumed, restart, released, ...)",
    "state": "text (raised or cleared; empty for a service event)",
    "value": "the indicator that crossed: 1 (a ratio) for leak and supply; s (the gap) for "
    "silent; 1 (the sequence number) for restart; NaN: none",
    "wall": "s (Unix time, the daemon's clock when it logged the event)",
    "detail": "JSON text (whatever else the event carries)",
}


def unit_of(name: str) -> str | None:
    """The unit of field ``name`` (``x_s_sigma``: x_s's; ``innov_p1``, ``ol_p1``: p1's), or
    None for a field this table does not know."""
    if name in UNITS:
        return UNITS[name]
    for pre in ("innov_", "ol_"):
        if name.startswith(pre) and name[len(pre) :] in UNITS:
            return UNITS[name[len(pre) :]].split(" (", 1)[0] + f" (residual of {name[len(pre) :]})"
    if name.endswith("_sigma") and name[: -len("_sigma")] in UNITS:
        return UNITS[name[: -len("_sigma")]].split(" (", 1)[0] + " (1-sigma)"
    return None


def units_of(names: tuple[str, ...] | list[str]) -> dict[str, str]:
    """``{field: unit}`` for the fields of ``names`` that have one."""
    return {n: u for n in names if (u := unit_of(n)) is not None}
