"""Monitor settings and the calibrated baseline: pydantic models, validated and frozen.

``MonitorConfig`` holds the filter's noise settings, alarm thresholds and limits; ``Baseline``
the nominal parameters of the simplified model (``service.monitor.calibration`` identifies them;
``Baseline.default`` is the calibration on the bundled healthy run).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from models.params import EHAParams
from models.valve_laws import LAW_NAMES
from service.monitor.model_choice import DEFAULT_MODEL, MONITOR_MODELS

if TYPE_CHECKING:  # the reduced model compiles (numba): imported where it is used
    from models import eha_reduced as er

assert (*LAW_NAMES, "WH") == MONITOR_MODELS, (
    "service.monitor.model_choice lists the monitor's models"
)

__all__ = [
    "MONITOR_MODELS",
    "DEFAULT_MODEL",
    "BaselineModelError",
    "check_baseline_model",
    "MeasurementNoise",
    "ProcessNoise",
    "AlarmConfig",
    "MonitorConfig",
    "Baseline",
]


class _Cfg(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class MeasurementNoise(_Cfg):
    """1-sigma measurement noise assumed by the filter (sensor noise plus model mismatch)."""

    x_s_m: float = Field(0.5e-6, gt=0, description="spool LVDT [m]")
    x_j_m: float = Field(50e-6, gt=0, description="jack LVDT [m]")
    p_pa: float = Field(55e3, gt=0, description="chamber pressure transducers [Pa]")
    p_sr_pa: float = Field(55e3, gt=0, description="supply pressure transducer [Pa]")


class ProcessNoise(_Cfg):
    """Random-walk intensities, 1-sigma growth per sqrt(second) (Q = q^2 dt)."""

    x_s: float = Field(2e-5, gt=0, description="spool position [m/sqrt(s)]")
    v_s: float = Field(2e-2, gt=0, description="spool velocity [m/s/sqrt(s)]")
    x_j: float = Field(2e-5, gt=0, description="jack position [m/sqrt(s)]")
    v_j: float = Field(5e-3, gt=0, description="jack velocity [m/s/sqrt(s)]")
    f_r: float = Field(2e3, gt=0, description="external load [N/sqrt(s)]")
    p_sr: float = Field(
        3e5,
        gt=0,
        description="supply [Pa/sqrt(s)]; small, as the adaptive step (adapt_p_sr) frees it "
        "on a supply change",
    )
    c_lk: float = Field(1.2e-13, gt=0, description="leakage [m^3/s/Pa/sqrt(s)]")
    i_b: float = Field(2e-6, gt=0, description="servovalve null bias [A/sqrt(s)]")
    p_ch: float = Field(
        1e6,
        gt=0,
        description="WH model only: chamber states p~1, p~2 [Pa/sqrt(s)]; with p_ch_common "
        "set, the differential mode (p~1 - p~2)/sqrt(2)",
    )
    p_ch_common: float = Field(
        1e5,
        gt=0,
        description="WH model only: common mode (p~1 + p~2)/sqrt(2) of the chamber states "
        "[Pa/sqrt(s)] (equal to p_ch: the chambers' walks uncorrelated)",
    )


class AlarmConfig(_Cfg):
    """Alarm thresholds with hysteresis (raise/clear levels) and a persistence time."""

    leak_raise: float = Field(2.5, gt=0, description="raise when C_Lk / baseline >= this")
    leak_clear: float = Field(2.0, gt=0, description="clear when C_Lk / baseline <= this")
    supply_raise: float = Field(0.85, gt=0, description="raise when P_SR / rated <= this")
    supply_clear: float = Field(0.90, gt=0, description="clear when P_SR / rated >= this")
    hold_s: float = Field(0.05, ge=0, description="condition must persist this long [s]")
    leak_max_sigma: float = Field(
        0.6, gt=0, description="raise a leak alarm only if sigma(C_Lk) / baseline is below this"
    )
    leak_z: float = Field(
        1.96,
        ge=0,
        description="... and only while C_Lk / baseline - leak_z x sigma(C_Lk) / baseline >= "
        "leak_clear: the clear level lies outside the estimate's band of +-leak_z sigma "
        "(1.96: the 95 % band of the NIS check; 0 = off; docs/estimation.md, Alarms)",
    )
    supply_max_sigma: float = Field(
        0.05, gt=0, description="raise a supply alarm only if sigma(P_SR) / rated is below this"
    )
    leak_mask_supply: float = Field(
        0.05,
        gt=0,
        description="supply transient: the P_SR estimate / rated leaves its value lagged by "
        "leak_mask_tau_s by more than this; the leak alarm then keeps its state (C_Lk and P_SR "
        "both explain the chamber pressures until P_SR has followed; docs/estimation.md, leak "
        "alarm during a supply transient)",
    )
    leak_mask_tau_s: float = Field(
        0.05, gt=0, description="time constant of the lagged supply ratio [s]"
    )
    leak_mask_s: float = Field(
        0.2,
        ge=0,
        description="the leak alarm keeps its state this long after a supply "
        "transient [s] (0 = off)",
    )


class MonitorConfig(_Cfg):
    """Monitor settings: one concrete default each, for every process model (chosen on WH,
    the default model; docs/estimation.md, "Settings", lists them all)."""

    model: str = Field(DEFAULT_MODEL, description=f"process model, one of {MONITOR_MODELS}")
    channels: Literal["full", "reduced"] = Field(
        "full", description="full: use every channel present; reduced: x_J only (+ i, x_cmd)"
    )
    noise: MeasurementNoise = Field(default_factory=MeasurementNoise)
    process: ProcessNoise = Field(default_factory=ProcessNoise)
    alarms: AlarmConfig = Field(default_factory=AlarmConfig)
    alpha: float = Field(0.5, gt=0, le=1, description="sigma-point spread (Merwe alpha)")
    beta: float = Field(2.0, description="sigma-point weight of the prior (Merwe beta)")
    kappa: float = Field(0.0, description="secondary sigma-point spread (Merwe kappa)")
    init_sigma_x_s: float = Field(2e-6, gt=0, description="initial spool position 1-sigma [m]")
    init_sigma_v_s: float = Field(1e-3, gt=0, description="initial spool velocity 1-sigma [m/s]")
    init_sigma_x_j: float = Field(1e-4, gt=0, description="initial jack position 1-sigma [m]")
    init_sigma_v_j: float = Field(5e-3, gt=0, description="initial jack velocity 1-sigma [m/s]")
    init_sigma_f_r: float = Field(5e3, gt=0, description="initial load 1-sigma [N]")
    init_sigma_p_sr: float = Field(2e6, gt=0, description="initial supply 1-sigma [Pa]")
    init_sigma_c_lk: float = Field(2e-13, gt=0, description="initial leakage 1-sigma")
    init_sigma_i_b: float = Field(2e-4, gt=0, description="initial null bias 1-sigma [A]")
    init_sigma_p_ch: float = Field(
        1e5, gt=0, description="WH model only: initial chamber-state 1-sigma [Pa]"
    )
    max_gap_s: float = Field(0.05, gt=0, description="longer sample gaps re-initialise [s]")
    nis_tau_s: float = Field(0.2, gt=0, description="time constant of the NIS average [s]")
    nis_reinit: float = Field(30.0, gt=1, description="re-init when mean NIS/dof exceeds this")
    c_lk_max: float = Field(1e-10, gt=0, description="upper clip of C_Lk [m^3/s/Pa]")
    arm_s: float = Field(0.5, ge=0, description="alarms armed this long after a (re)init [s]")
    c_lk_gate_v: float = Field(
        0.01,
        gt=0,
        description="C_Lk is learnt only while |v_J| is below this [m/s] "
        "(docs/estimation.md, observability gate)",
    )
    c_lk_gate_x_u: float = Field(
        1.0,
        ge=0,
        description="... and with |x_S| within this many land underlaps x_u (0 = off)",
    )
    c_lk_gate_nis: float = Field(
        5.0,
        gt=0,
        description="... and while the NIS/dof average is below this (the model explains the data)",
    )
    c_lk_gate_p12: float = Field(
        0.05,
        ge=0,
        lt=1,
        description="... and while the measured |P1 - P2|, low-passed (c_lk_gate_p12_tau_s), "
        "is above this share of rated P_SR (0 = off; docs/estimation.md, observability gate)",
    )
    c_lk_gate_p12_tau_s: float = Field(
        0.05,
        ge=0,
        description="... that |P1 - P2| low-passed over the samples before this one, with this "
        "time constant [s] (0 = the sample's own value; docs/estimation.md, observability gate)",
    )
    c_lk_gated_sigma_max: float = Field(
        0.7,
        ge=0,
        description="while the gate holds C_Lk its variance grows with the walk up to this "
        "sigma, as a share of baseline C_Lk (0 = no cap)",
    )
    c_lk_gate_flow: float = Field(
        5.0,
        ge=0,
        description="... and while the jack's flow A |v_J| is below this many times the "
        "baseline leak flow C_Lk |P12| (|P12| as the gate's low-pass; 0 = off; "
        "docs/estimation.md, a speed gate relative to the leak flow)",
    )
    c_lk_gate_flow_s: float = Field(
        0.3,
        ge=0,
        description="... only within this long [s] after the estimated |v_J| last exceeded "
        "c_lk_gate_flow_v_fast (0 = always)",
    )
    c_lk_gate_flow_v_fast: float = Field(
        0.1,
        gt=0,
        description="fast motion for c_lk_gate_flow_s [m/s]: a slew to a step, faster than "
        "the jack follows a commanded ramp (docs/decisions/0002-wh-c-lk-walk.md)",
    )
    c_lk_gate_adapt: float = Field(
        20.0,
        ge=0,
        description="... and on a sample whose adaptive process-noise scale (NIS/dof / "
        "adapt_nis) exceeds this (0 = off)",
    )
    i_b_gate_x_u: float = Field(
        1.0,
        ge=0,
        description="the null bias i_b is held (Schmidt update) while |x_S| exceeds this many "
        "underlaps x_u: the spool model (a linear lag) does not follow a spool opened past it "
        "(0 = off; docs/estimation.md, observability gate)",
    )
    c_lk_cusum_h: float = Field(
        10.0,
        ge=0,
        description="C_Lk change detector: threshold of the two-sided CUSUM of the "
        "standardised C_Lk updates (0 = off; docs/estimation.md, C_Lk change detector (WH))",
    )
    c_lk_cusum_nu: float = Field(0.5, ge=0, description="... its drift per sample")
    c_lk_cusum_kick: float = Field(
        0.5,
        gt=0,
        description="... on a detection, C_Lk's 1-sigma grows by this share of the "
        "baseline C_Lk (in quadrature)",
    )
    c_lk_pool_h: float = Field(
        6.9,
        ge=0,
        description="the pooled C_Lk (everything learnt since the last detected change) has "
        "its own change test: the threshold of its Page CUSUM, a log-likelihood ratio "
        "(6.9 = ln 1000: Wald's bound puts a false restart at 1e-3; 0 = off; "
        "docs/estimation.md, the pooled C_Lk)",
    )
    c_lk_pool_tol: float = Field(
        0.1,
        gt=0,
        description="... its design shift: this share of the increase the pool reads, "
        "|pooled / baseline - 1|, at least c_lk_pool_d_min (0.1: the 10 % target)",
    )
    c_lk_pool_d_min: float = Field(
        0.5,
        gt=0,
        description="... the smallest increase it scales with, as a share of baseline C_Lk "
        "(0.5: the leak alarm's band, leak_raise - leak_clear); the pooled reading's "
        "observability limit uses the same two (service.prognostics.indicators)",
    )
    p_sr_max_ratio: float = Field(
        1.05,
        ge=1,
        le=2,
        description="upper clip of the P_SR estimate as a share of rated (a clip at rated "
        "biases an uncertain estimate low)",
    )
    adapt_nis: float = Field(
        1.5,
        ge=0,
        description="adaptive process noise: a sample whose NIS/dof exceeds this is redone with "
        "the plant states' process noise scaled by NIS/dof / adapt_nis (0 = off; "
        "docs/estimation.md, adaptive process noise)",
    )
    adapt_max: float = Field(
        100.0, ge=1, description="largest process-noise scale of the adaptive step"
    )
    adapt_p_sr: float = Field(
        2.0,
        ge=0,
        description="exponent k: the adaptive step scales P_SR's random walk by g^k (g = "
        "NIS/dof / adapt_nis), at most adapt_max, so that a supply change frees it at once "
        "and small misfits leave it alone; 0 = held (the plant states only)",
    )
    adapt_reinit: float = Field(
        3e3,
        gt=1,
        description="with adaptive process noise on, one sample whose NIS/dof exceeds this "
        "re-initialises (no plant transient explains it: a dead or swapped sensor)",
    )

    threads: int = Field(
        2,
        ge=1,
        le=2,
        description="threads that step a block of samples: 2 splits its actuators between "
        "the caller's thread and one more (the same numbers; blocks of 64 samples and more)",
    )

    @field_validator("model")
    @classmethod
    def _known_model(cls, v: str) -> str:
        if v not in MONITOR_MODELS:
            raise ValueError(f"unknown model {v!r}; expected one of {', '.join(MONITOR_MODELS)}")
        return v

    reduced_param_q: float = Field(
        0.01,
        ge=0,
        description="reduced channel set: scale of the P_SR, C_Lk, i_b random walks (they are "
        "not observable from x_J alone, see docs/estimation.md)",
    )


class Baseline(_Cfg):
    """Calibrated nominal parameters of the simplified model (see ``service.monitor.calibration``).

    ``x_ss``/``g_pq`` are effective values that absorb the C-type/HF mismatch near null
    (physics.md section 3: only 1/G_PQ + C_Lk is identifiable at null, so C_Lk stays at its
    nominal value and the effective 1/G_PQ takes the rest).
    """

    law: str = Field(
        description="the process model this baseline is for (MONITOR_MODELS); a monitor on "
        "another model refuses it (check_baseline_model)"
    )
    g_pq: float = Field(gt=0)
    x_ss: float = Field(gt=0)
    c_lk: float = Field(ge=0)
    p_r: float = Field(gt=0)
    p_sr_rated: float = Field(gt=0)
    g_pq_exp: float = Field(
        0.5, ge=0, description="G_PQ ~ (P_SR/rated)^exp; 0.5 per physics.md section 3, 0 = seed"
    )
    area: float = 1e-3
    mass: float = 100.0
    c_v: float = 2000.0
    f_d: float = 400.0
    v_f: float = 2e-3
    f_s: float = Field(
        0.0,
        ge=0,
        description="WH model only: breakaway (static) friction F_s [N], the datasheet's; the "
        "jack sticks while |A P12 - F_R| <= F_s; 0 = smooth friction only "
        '(docs/estimation.md, "Stiction in the WH process model")',
    )
    v_stick: float = Field(
        3e-4,
        gt=0,
        description="WH model only: stick band [m/s], about twice the filter's v_J walk per "
        "1 ms sample (5e-3 m/s/sqrt(s) x sqrt(1 ms) = 0.16 mm/s)",
    )
    k_sv: float = 0.05
    x_sm: float = 5e-4
    omega_n: float = 2 * math.pi * 150.0
    zeta: float = 0.7
    k_p: float = 2.0
    i_max: float = 0.01
    x_u: float = Field(
        1e-4, ge=0, description="land underlap [m]; the flow gain halves beyond it (0 = off)"
    )
    x_0: float = Field(
        0.0, description="hydraulic null of the spool [m] (land mismatch), from calibration"
    )
    skew: float = Field(
        0.0,
        gt=-0.5,
        lt=0.5,
        description="WH model only: land underlap skew, supply lands x_SS (1 + skew), return "
        "lands x_SS (1 - skew); sets the chamber pressures at null (P_k - P_R) / P_SR = "
        "k^2 / (1 + k^2), k = (1 + skew) / (1 - skew); from calibration",
    )
    c_land: float = Field(
        0.0,
        ge=0,
        description="WH model only: laminar leak through the lands' radial clearance "
        "[m^3/(s Pa)], a cross-port leak added to C_Lk that does not scale with the supply "
        '(docs/estimation.md, "Land clearance leak (WH)"); nominal from the valve\'s design',
    )
    v_c: float = Field(7e-5, gt=0, description="WH model only: lumped chamber volume V [m^3]")
    beta: float = Field(1.4e9, gt=0, description="WH model only: lumped bulk modulus [Pa]")
    source: str = "nominal"

    @classmethod
    def nominal(cls, law: str = DEFAULT_MODEL, params: EHAParams | None = None) -> Baseline:
        """Uncalibrated values derived from the HF parameter set (physics.md section 3)."""
        from models import eha_reduced as er

        p = params or EHAParams()
        rp = er.reduced_params(params, law)._asdict()
        fields = {k: v for k, v in rp.items() if k in cls.model_fields}
        # WH: V = V0 (mid-stroke chamber) and beta_l, as models.params.wh_params
        fields["c_land"] = p.g_lam_open if law == "WH" else 0.0
        fields["f_s"] = p.f_s if law == "WH" else 0.0  # WH: the jack sticks (Karnopp)
        return cls(**fields, c_lk=p.c_lk, v_c=p.v0, beta=p.beta_l, source="nominal")

    @classmethod
    def default(cls, law: str = DEFAULT_MODEL) -> Baseline:
        """The baseline calibrated on the bundled healthy HF run (``servowatch calibrate``);
        nominal values for a law without a stored calibration (WH: its datasheet values)."""
        cal = _DEFAULT_CALIBRATION.get(law)
        base = cls.nominal(law)
        if cal is None:
            return base
        return base.model_copy(update={**cal, "source": "default calibration (healthy_noise)"})

    def reduced_params(self) -> er.ReducedParams:
        """Parameters of ``models.eha_reduced`` for this baseline."""
        from models import eha_reduced as er

        return er.ReducedParams(
            **{
                k: getattr(self, k)
                for k in er.ReducedParams._fields
                if k in type(self).model_fields
            }
        )

    def save(self, path: str | Path) -> None:
        """Write as JSON."""
        Path(path).write_text(json.dumps(self.model_dump(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> Baseline:
        """Read a JSON file written by ``save``."""
        return cls.model_validate_json(Path(path).read_text())


class BaselineModelError(ValueError):
    """A baseline identified for one process model offered to a monitor on another."""

    def __init__(self, baseline_model: str, monitor_model: str, what: str = "baseline"):
        self.baseline_model, self.monitor_model = baseline_model, monitor_model
        super().__init__(
            f"{what} is for process model {baseline_model}, the monitor runs {monitor_model}: "
            f"recalibrate it for {monitor_model} (servowatch calibrate --model "
            f"{monitor_model}) or run the monitor on {baseline_model} (model = "
            f'"{baseline_model}")'
        )


def check_baseline_model(baseline: Baseline, model: str, what: str = "baseline") -> None:
    """Raise ``BaselineModelError`` unless ``baseline`` was identified for ``model``: a
    baseline's parameters are effective values of its own model (``Baseline``), never
    carried over to another."""
    if baseline.law != model:
        raise BaselineModelError(baseline.law, model, what)


# Effective parameters identified by ``servowatch calibrate --scenario healthy_noise`` on the
# HF bench (see docs/estimation.md); updated when the calibration is re-run.
_CAL_HEALTHY_NOISE = {
    "g_pq": 699248516557.714,
    "x_ss": 5.296400035013844e-05,
    "p_r": 482297.1298008915,
}
# near null every C-law reduces to the same linear form, so one calibration serves them all
_DEFAULT_CALIBRATION: dict[str, dict[str, float]] = dict.fromkeys(LAW_NAMES, _CAL_HEALTHY_NOISE)
# WH (models.eha_reduced_wh) has none: its parameters are the valve's datasheet (geometric)
# values, Baseline.nominal. A calibration on the bundled 4 s healthy run cannot do better: it
# fixes WH's null pressure coefficient only to about 1 % of C_Lk, and over 8 sensor-noise
# seeds its law reads -0.56 to +3.18 % of C_Lk at the HF plant's static holds (rated and 0.7
# of rated supply, 1-5x leak) against +0.02 to +0.20 % for the datasheet values
# (``evaluation/holds.py --calibrated-seeds 8``; docs/estimation.md,
# "WH's default baseline: the datasheet values"). A unit is still calibrated on its own run
# (``servowatch calibrate --model WH``), which fits its null where the run holds.
