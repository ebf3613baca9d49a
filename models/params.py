"""Reference parameter set of the EHA (physics.md section 4) and the simplified-valve
parameters derived from it (physics.md section 3, "Consistency with the simplified models").

One source of truth: the simplified laws' G_P, G_Q, G_PQ and x_SS are computed from the HF
geometry and fluid, never stored twice. All values SI.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = [
    "EHAParams",
    "ValveParams",
    "WHParams",
    "simplified_params",
    "wh_params",
    "DEFAULT_PARAMS",
]


class EHAParams(BaseModel):
    """Every physical parameter of the EHA bench (HF valve, fluid, servovalve, jack, ECU)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    # supply / return (absolute pressures, Pa)
    p_s: float = Field(20.5e6, gt=0, description="supply pressure, absolute [Pa]")
    p_r: float = Field(0.5e6, gt=0, description="return pressure, absolute [Pa]")
    # valve geometry
    c_lk: float = Field(2e-13, ge=0, description="cross-port leakage coefficient [m^3/s/Pa]")
    u1: float = Field(1e-4, description="land 1 (S->1) underlap, >0 underlap, <0 overlap [m]")
    u2: float = Field(1e-4, description="land 2 (1->R) underlap [m]")
    u3: float = Field(1e-4, description="land 3 (S->2) underlap [m]")
    u4: float = Field(1e-4, description="land 4 (2->R) underlap [m]")
    cd: float = Field(0.61, gt=0, description="discharge coefficient [-]")
    w: float | None = Field(
        None,
        description="port width [m]; None derives it from the seed's G_PQ (physics.md section 3)",
    )
    g_pq_seed: float = Field(7.4e11, gt=0, description="seed G_PQ used to derive w [Pa s/m^3]")
    x_sm: float = Field(5e-4, gt=0, description="spool stroke limit [m]")
    c_r: float = Field(2.5e-6, gt=0, description="radial clearance [m]")
    l_min: float = Field(5e-6, gt=0, description="minimum leakage path length [m]")
    dp_tr: float = Field(0.1e6, gt=0, description="turbulent/laminar transition pressure [Pa]")
    # fluid
    rho: float = Field(850.0, gt=0, description="density [kg/m^3]")
    mu: float = Field(0.0119, gt=0, description="dynamic viscosity [Pa s]")
    beta_l: float = Field(1.4e9, gt=0, description="liquid bulk modulus [Pa]")
    alpha0: float = Field(0.002, ge=0, description="entrained air fraction at P_atm [-]")
    kappa: float = Field(1.4, gt=0, description="polytropic exponent of the air [-]")
    p_vap: float = Field(1e3, gt=0, description="vapour pressure [Pa]")
    p_atm: float = Field(101.3e3, gt=0, description="atmospheric pressure [Pa]")
    # servovalve electromechanics
    i_max: float = Field(0.01, gt=0, description="current limit [A]")
    k_sv: float = Field(0.05, gt=0, description="spool position per current [m/A]")
    tau_tm: float = Field(5e-4, gt=0, description="torque motor time constant [s]")
    f_n: float = Field(150.0, gt=0, description="spool natural frequency [Hz]")
    zeta: float = Field(0.7, gt=0, description="spool damping ratio [-]")
    # jack
    area: float = Field(1e-3, gt=0, description="piston area A [m^2]")
    stroke: float = Field(0.05, gt=0, description="half stroke, end stops at +-stroke [m]")
    v_dead: float = Field(20e-6, gt=0, description="dead volume per side [m^3]")
    mass: float = Field(100.0, gt=0, description="moving mass [kg]")
    c_v: float = Field(2000.0, ge=0, description="viscous friction [N s/m]")
    f_s: float = Field(600.0, ge=0, description="static (breakaway) friction [N]")
    f_d: float = Field(400.0, ge=0, description="dynamic (Coulomb) friction [N]")
    dv_k: float = Field(1e-4, gt=0, description="Karnopp stick velocity band [m/s]")
    k_stop: float = Field(1e8, ge=0, description="end-stop stiffness [N/m]")
    c_stop: float = Field(1e5, ge=0, description="end-stop damping [N s/m]")
    # ECU
    k_p: float = Field(2.0, gt=0, description="position loop gain [A/m]")

    @model_validator(mode="after")
    def _check(self) -> EHAParams:
        if self.p_s <= self.p_r:
            raise ValueError("p_s must exceed p_r")
        if self.f_d > self.f_s:
            raise ValueError("f_d (Coulomb) must not exceed f_s (breakaway)")
        return self

    # -- derived quantities (physics.md section 3) ---------------------------------------
    @property
    def p_sr(self) -> float:
        """Rated supply-return pressure difference P_SR = P_S - P_R [Pa]."""
        return self.p_s - self.p_r

    @property
    def x_ss(self) -> float:
        """Saturation spool displacement x_SS = u (underlap of land 1) [m]."""
        return abs(self.u1)

    @property
    def w_eff(self) -> float:
        """Port width w = sqrt(P_SR rho) / (Cd x_SS G_PQ) unless given explicitly [m]."""
        if self.w is not None:
            return self.w
        return math.sqrt(self.p_sr * self.rho) / (self.cd * self.x_ss * self.g_pq_seed)

    @property
    def g_q(self) -> float:
        """No-load flow gain G_Q = Cd w sqrt(P_SR / rho) [m^2/s]."""
        return self.cd * self.w_eff * math.sqrt(self.p_sr / self.rho)

    @property
    def g_p(self) -> float:
        """Secant pressure gain G_P = P_SR / x_SS [Pa/m]."""
        return self.p_sr / self.x_ss

    @property
    def g_pq(self) -> float:
        """G_PQ = G_P / G_Q [Pa s/m^3]."""
        return self.g_p / self.g_q

    @property
    def g_lam_open(self) -> float:
        """Laminar clearance conductance of an open land, G_lam = w c_r^3 / (12 mu l_min)
        [m^3/(s Pa)] (physics.md section 3.2). With all four lands open and matched it acts
        as a cross-port leak of the same coefficient, independent of the supply."""
        return self.w_eff * self.c_r**3 / (12.0 * self.mu * self.l_min)

    @property
    def v0(self) -> float:
        """Chamber volume at mid stroke V0 = A stroke + V_dead [m^3]."""
        return self.area * self.stroke + self.v_dead

    @property
    def omega_n(self) -> float:
        """Spool natural angular frequency [rad/s]."""
        return 2.0 * math.pi * self.f_n

    def with_overrides(self, **overrides: float) -> EHAParams:
        """A copy with some fields changed (validated)."""
        return EHAParams.model_validate({**self.model_dump(), **overrides})


class ValveParams(NamedTuple):
    """Parameters of the simplified laws A, B, C1, C3, C5 (physics.md section 2)."""

    g_pq: float  # Pa s/m^3
    x_ss: float  # m
    c_lk: float  # m^3/s/Pa
    p_vap: float  # Pa


def simplified_params(p: EHAParams) -> ValveParams:
    """Derive the simplified laws' parameters from the HF parameter set."""
    return ValveParams(g_pq=p.g_pq, x_ss=p.x_ss, c_lk=p.c_lk, p_vap=p.p_vap)


class WHParams(NamedTuple):
    """Parameters of the WH valve model (docs/models.md section 2): the C-types' four, the
    rated supply at which G_PQ was measured, the return pressure and a lumped chamber
    compliance V / beta. ``k_o`` and ``dp_lam`` are derived (docs/models.md eqs. 2, 3)."""

    g_pq: float  # Pa s/m^3, at the rated P_SR
    x_ss: float  # m
    c_lk: float  # m^3/s/Pa
    p_vap: float  # Pa (absolute)
    p_sr_nom: float  # Pa, rated P_SR of the datasheet (G_PQ, G_Q measured there)
    p_r: float  # Pa (absolute return pressure)
    v_c: float  # m^3, lumped chamber volume
    beta: float  # Pa, lumped bulk modulus

    @property
    def k_o(self) -> float:
        """Land orifice coefficient K_o = sqrt(2 P_SR,nom) / (x_SS G_PQ) [m^2/s/sqrt(Pa)] (eq. 2)."""
        return math.sqrt(2.0 * self.p_sr_nom) / (self.x_ss * self.g_pq)

    @property
    def dp_lam(self) -> float:
        """Laminar band of each land dp_lam = 5e-3 P_SR,nom [Pa] (eq. 3, numerical)."""
        return WH_DP_LAM_FRACTION * self.p_sr_nom


WH_DP_LAM_FRACTION = 5e-3
"""Width of each land's linear (laminar) band as a fraction of the rated P_SR (0.1 MPa at
20 MPa): removes the infinite slope of sqrt(dp) at dp = 0 (docs/models.md eq. 3)."""


def wh_params(p: EHAParams) -> WHParams:
    """The WH model's parameters from the HF parameter set: the C-types' G_PQ, x_SS, C_Lk,
    P_vap at the rated P_SR, the return pressure, V = V0 (mid-stroke chamber) and beta_l."""
    return WHParams(
        g_pq=p.g_pq,
        x_ss=p.x_ss,
        c_lk=p.c_lk,
        p_vap=p.p_vap,
        p_sr_nom=p.p_sr,
        p_r=p.p_r,
        v_c=p.v0,
        beta=p.beta_l,
    )


DEFAULT_PARAMS = EHAParams()
