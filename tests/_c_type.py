"""The C-types' filter of the bundled scenarios (the settings the C-type figures and hashes were
taken with before WH became the default; docs/estimation.md, "Settings")."""

from service.monitor import MonitorConfig

C_TYPE_SETTINGS = {
    "adapt_nis": 0.0,
    "adapt_p_sr": 0.0,
    "c_lk_gate_adapt": 0.0,
    "c_lk_cusum_h": 0.0,
    "c_lk_gate_p12": 0.0,
    "c_lk_gated_sigma_max": 0.0,
    "i_b_gate_x_u": 0.0,
    "p_sr_max_ratio": 1.0,
    "c_lk_gate_flow": 0.0,
    "c_lk_gate_flow_s": 0.0,
    "process": {"p_sr": 2e6, "c_lk": 1e-13, "p_ch_common": 1e6},
    "alarms": {"leak_max_sigma": 1.0, "leak_z": 0.0},
}


def c_type_config(model: str = "C5", **overrides) -> MonitorConfig:
    """``MonitorConfig`` of the C-types' filter on ``model``, with ``overrides``."""
    return MonitorConfig.model_validate({**C_TYPE_SETTINGS, "model": model, **overrides})
