"""Per-actuator health monitor: a UKF on the simplified (C-type) EHA model, no I/O.

Samples in, estimates out. ``Monitor`` serves one actuator; ``MonitorBank`` serves many in one
vectorised update (all sigma points of all actuators through ``models.eha_reduced.step`` in
one call). ``Monitor`` is a ``MonitorBank`` of one, so both run the same code; element-wise
numpy and per-matrix LAPACK calls make the result independent of the batch size
(``tests/test_monitor.py`` checks bit equality).

Filter state (SI; scaled internally so that the default noise settings need no tuning):
x_s, v_s, x_j, v_j (plant), f_r (external load), p_sr (supply), c_lk (internal leakage), the
last three as random walks. Inputs: servovalve current i (measured; else the ECU law on
x_cmd). Measurements: any of x_s, x_j, p1, p2, p_sr. See docs/estimation.md.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from numba import njit
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from models import eha_reduced as er
from models.eha_reduced import measure_nb, spool_coef_nb, step_core_nb
from models.params import EHAParams
from models.valve_laws import LAW_NAMES
from service.ukf import BatchUKF, borrowed_all, ukf_one, workspace

__all__ = [
    "MeasurementNoise",
    "ProcessNoise",
    "AlarmConfig",
    "MonitorConfig",
    "Baseline",
    "AlarmEvent",
    "MonitorOutput",
    "Monitor",
    "MonitorBank",
    "BankRows",
    "MEAS_CHANNELS",
    "ALARM_KINDS",
    "EST_KEYS",
    "RES_KEYS",
    "HEALTH_KEYS",
]

log = logging.getLogger(__name__)

MEAS_CHANNELS: tuple[str, ...] = er.MEAS_NAMES  # x_s, x_j, p1, p2, p_sr
ALARM_KINDS: tuple[str, ...] = ("leak", "supply")
_NX = er.N_STATES


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

    x_s: float = Field(2e-5, gt=0, description="[m/sqrt(s)]")
    v_s: float = Field(2e-2, gt=0, description="[m/s/sqrt(s)]")
    x_j: float = Field(2e-5, gt=0, description="[m/sqrt(s)]")
    v_j: float = Field(5e-3, gt=0, description="[m/s/sqrt(s)]")
    f_r: float = Field(2e3, gt=0, description="external load [N/sqrt(s)]")
    p_sr: float = Field(2e6, gt=0, description="supply [Pa/sqrt(s)]")
    c_lk: float = Field(1e-13, gt=0, description="leakage [m^3/s/Pa/sqrt(s)]")
    i_b: float = Field(2e-6, gt=0, description="servovalve null bias [A/sqrt(s)]")


class AlarmConfig(_Cfg):
    """Alarm thresholds with hysteresis (raise/clear levels) and a persistence time."""

    leak_raise: float = Field(2.5, gt=0, description="raise when C_Lk / baseline >= this")
    leak_clear: float = Field(2.0, gt=0, description="clear when C_Lk / baseline <= this")
    supply_raise: float = Field(0.85, gt=0, description="raise when P_SR / rated <= this")
    supply_clear: float = Field(0.90, gt=0, description="clear when P_SR / rated >= this")
    hold_s: float = Field(0.05, ge=0, description="condition must persist this long [s]")
    leak_max_sigma: float = Field(
        1.0, gt=0, description="raise a leak alarm only if sigma(C_Lk) / baseline is below this"
    )
    supply_max_sigma: float = Field(
        0.05, gt=0, description="raise a supply alarm only if sigma(P_SR) / rated is below this"
    )


class MonitorConfig(_Cfg):
    """Monitor settings; every default works on the bundled scenarios without tuning."""

    model: str = Field("C5", description=f"valve law, one of {LAW_NAMES}")
    channels: Literal["full", "reduced"] = Field(
        "full", description="full: use every channel present; reduced: x_J only (+ i, x_cmd)"
    )
    noise: MeasurementNoise = Field(default_factory=MeasurementNoise)
    process: ProcessNoise = Field(default_factory=ProcessNoise)
    alarms: AlarmConfig = Field(default_factory=AlarmConfig)
    alpha: float = Field(0.5, gt=0, le=1, description="sigma-point spread (Merwe alpha)")
    beta: float = 2.0
    kappa: float = 0.0
    init_sigma_f_r: float = Field(5e3, gt=0, description="initial load 1-sigma [N]")
    init_sigma_p_sr: float = Field(2e6, gt=0, description="initial supply 1-sigma [Pa]")
    init_sigma_c_lk: float = Field(2e-13, gt=0, description="initial leakage 1-sigma")
    init_sigma_i_b: float = Field(2e-4, gt=0, description="initial null bias 1-sigma [A]")
    max_gap_s: float = Field(0.05, gt=0, description="longer sample gaps re-initialise [s]")
    nis_tau_s: float = Field(0.2, gt=0, description="time constant of the NIS average [s]")
    nis_reinit: float = Field(30.0, gt=1, description="re-init when mean NIS/dof exceeds this")
    c_lk_max: float = Field(1e-10, gt=0, description="upper clip of C_Lk [m^3/s/Pa]")
    arm_s: float = Field(0.5, ge=0, description="alarms armed this long after a (re)init [s]")
    c_lk_gate_v: float = Field(
        0.01,
        gt=0,
        description="C_Lk is learnt only while |v_J| is below this [m/s] and the spool within "
        "its underlap (docs/estimation.md, observability gate)",
    )
    c_lk_gate_nis: float = Field(
        5.0,
        gt=0,
        description="... and while the NIS/dof average is below this (the model explains the data)",
    )
    reduced_param_q: float = Field(
        0.01,
        ge=0,
        description="reduced channel set: scale of the P_SR, C_Lk, i_b random walks (they are "
        "not observable from x_J alone, see docs/estimation.md)",
    )


class Baseline(_Cfg):
    """Calibrated nominal parameters of the simplified model (see ``service.calibration``).

    ``x_ss``/``g_pq`` are effective values that absorb the C-type/HF mismatch near null
    (physics.md section 3: only 1/G_PQ + C_Lk is identifiable at null, so C_Lk stays at its
    nominal value and the effective 1/G_PQ takes the rest).
    """

    law: str = "C5"
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
    source: str = "nominal"

    @classmethod
    def nominal(cls, law: str = "C5", params: EHAParams | None = None) -> Baseline:
        """Uncalibrated values derived from the HF parameter set (physics.md section 3)."""
        rp = er.reduced_params(params, law)._asdict()
        fields = {k: v for k, v in rp.items() if k in cls.model_fields}
        return cls(**fields, c_lk=(params or EHAParams()).c_lk, source="nominal")

    @classmethod
    def default(cls, law: str = "C5") -> Baseline:
        """The baseline calibrated on the bundled healthy HF run (``servowatch calibrate``);
        nominal values for a law without a stored calibration."""
        cal = _DEFAULT_CALIBRATION.get(law)
        base = cls.nominal(law)
        if cal is None:
            return base
        return base.model_copy(update={**cal, "source": "default calibration (healthy_noise)"})

    def reduced_params(self) -> er.ReducedParams:
        """Parameters of ``models.eha_reduced`` for this baseline."""
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


# Effective parameters identified by ``servowatch calibrate --scenario healthy_noise`` on the
# HF bench (see docs/estimation.md); updated when the calibration is re-run.
_CAL_HEALTHY_NOISE = {
    "g_pq": 699248516557.714,
    "x_ss": 5.296400035013844e-05,
    "p_r": 482297.1298008915,
}
# near null every C-law reduces to the same linear form, so one calibration serves them all
_DEFAULT_CALIBRATION: dict[str, dict[str, float]] = dict.fromkeys(LAW_NAMES, _CAL_HEALTHY_NOISE)


@dataclass
class AlarmEvent:
    """An alarm raised or cleared at time ``t`` (``value`` is the indicator that crossed)."""

    t: float
    kind: str
    state: Literal["raised", "cleared"]
    value: float


@dataclass
class MonitorOutput:
    """One accepted sample's estimates (flat dicts of floats, never NaN)."""

    t: float
    est: dict[str, float]
    res: dict[str, float]
    health: dict[str, float]
    events: list[AlarmEvent] = field(default_factory=list)


class RowEvents(Sequence):
    """The alarm events of each output row, stored sparsely (most rows have none): a
    sequence of lists, ``[]`` for a row without events. A list per row would be one
    garbage-collected allocation per sample, which cost as much as the filter step."""

    __slots__ = ("_n", "_at")

    def __init__(self, n: int, at: dict[int, list[AlarmEvent]] | None = None):
        self._n = n
        self._at = at or {}

    @classmethod
    def of(cls, lists: Sequence[list[AlarmEvent]]) -> RowEvents:
        """From one list per row."""
        return cls(len(lists), {r: ev for r, ev in enumerate(lists) if ev})

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, r):  # type: ignore[override]
        if isinstance(r, slice):
            return [self[i] for i in range(*r.indices(self._n))]
        if r < 0:
            r += self._n
        if not 0 <= r < self._n:
            raise IndexError("RowEvents index out of range")
        ev = self._at.get(r)
        return [] if ev is None else ev

    def __eq__(self, other: object) -> bool:
        if isinstance(other, RowEvents):
            return self._n == other._n and self._at == other._at
        if isinstance(other, Sequence):
            return list(self) == list(other)
        return NotImplemented

    def __repr__(self) -> str:
        return f"RowEvents({self._n}, {self._at!r})"

    def rows(self) -> list[int]:
        """The rows that have events, ascending."""
        return sorted(self._at)

    def flags(self) -> NDArray:
        """(n,) bool: the row has events."""
        f = np.zeros(self._n, bool)
        if self._at:
            f[list(self._at)] = True
        return f


@dataclass
class BankRows:
    """Outputs of ``MonitorBank.update_rows``: one row per accepted sample, in input order.
    Columns are named by ``EST_KEYS``, ``RES_KEYS`` and ``HEALTH_KEYS`` (same values as the
    dicts of ``MonitorOutput``)."""

    index: NDArray  # (R,) position of each accepted sample in the input sequence
    t: NDArray  # (R,)
    est: NDArray  # (R, len(EST_KEYS))
    res: NDArray  # (R, len(RES_KEYS))
    health: NDArray  # (R, len(HEALTH_KEYS))
    events: RowEvents  # a sequence of lists, one per row
    _lists: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _n_out: int = field(default=0, init=False, repr=False, compare=False)

    def output(self, r: int) -> MonitorOutput:
        """Row ``r`` as a ``MonitorOutput``."""
        c = self._lists
        if c is None:
            self._n_out += 1
            if 8 * self._n_out < len(self.t):
                return MonitorOutput(
                    t=float(self.t[r]),
                    est=dict(zip(EST_KEYS, self.est[r].tolist(), strict=True)),
                    res=dict(zip(RES_KEYS, self.res[r].tolist(), strict=True)),
                    health=dict(zip(HEALTH_KEYS, self.health[r].tolist(), strict=True)),
                    events=self.events[r],
                )
            # many rows wanted: convert the arrays once (same floats, fewer calls)
            c = self._lists = (
                self.t.tolist(), self.est.tolist(), self.res.tolist(), self.health.tolist()
            )  # fmt: skip
        return MonitorOutput(
            t=c[0][r],
            est=dict(zip(EST_KEYS, c[1][r], strict=True)),
            res=dict(zip(RES_KEYS, c[2][r], strict=True)),
            health=dict(zip(HEALTH_KEYS, c[3][r], strict=True)),
            events=self.events[r],
        )


@dataclass
class StepBlock:
    """A block of samples stepped through the filters (``MonitorBank.step_arrays``) whose
    output rows are still to be made (``MonitorBank.rows_of``): inputs, innovations, NIS,
    which samples have a row (acc) and the state snapshot of each (X, diagonal of P, OL,
    T_INIT, NIS_AVG), and the re-initialisation events by sample."""

    ks: NDArray
    t: NDArray
    z: NDArray
    mask: NDArray
    y: NDArray
    nis: NDArray
    acc: NDArray
    snap: tuple[NDArray, NDArray, NDArray, NDArray, NDArray]
    extra: dict[int, list[AlarmEvent]]


_COUNTERS = (
    "accepted",
    "skipped_nan",
    "skipped_time",
    "missing_channel",
    "bad_channel",
    "reinit",
    "gap",
)


_PLAIN = {float, int, type(None), np.float64}


def _empty_rows() -> BankRows:
    z = np.zeros((0,))
    return BankRows(np.zeros(0, int), z, z.reshape(0, len(_EST_KEYS)),
                    z.reshape(0, len(_RES_KEYS)), z.reshape(0, len(_HEALTH_KEYS)), RowEvents(0))  # fmt: skip


def _f(v) -> float | None:
    """A finite float or None."""
    if v is None:
        return None
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


class MonitorBank:
    """Monitors for many actuators advanced together in one vectorised UKF update."""

    def __init__(
        self,
        config: MonitorConfig | None = None,
        baseline: Baseline | None = None,
        capacity: int = 8,
    ):
        self.config = config or MonitorConfig()
        if self.config.model not in LAW_NAMES:
            raise ValueError(f"unknown model {self.config.model!r}; expected one of {LAW_NAMES}")
        self.baseline = baseline or Baseline.default(self.config.model)
        if self.baseline.law != self.config.model:
            self.baseline = self.baseline.model_copy(update={"law": self.config.model})
        self.rp = self.baseline.reduced_params()
        b, c = self.baseline, self.config
        self.scale = np.array(
            [b.x_ss, b.x_ss * b.omega_n, 1e-3, 1e-2, 1e3, 1e6, 1e-13, 1e-4], float
        )  # filter units
        pn = c.process
        q = np.array([pn.x_s, pn.v_s, pn.x_j, pn.v_j, pn.f_r, pn.p_sr, pn.c_lk, pn.i_b])
        if c.channels == "reduced":
            q[5:8] *= c.reduced_param_q
        self._q = (q / self.scale) ** 2
        nz = c.noise
        r = np.array([nz.x_s_m, nz.x_j_m, nz.p_pa, nz.p_pa, nz.p_sr_pa])
        self._zscale = np.array([b.x_ss, 1e-3, 1e6, 1e6, 1e6])
        self.R = np.diag((r / self._zscale) ** 2)
        self._use = np.ones(5, bool) if c.channels == "full" else np.array([0, 1, 0, 0, 0], bool)
        # channels whose absence is counted (the supply transducer is optional)
        self._expect = self._use & np.array([1, 1, 1, 1, 0], bool)
        self._expect_idx = [int(c) for c in np.flatnonzero(self._expect)]
        self._chan = [
            (c, name, float(self._zscale[c]))
            for c, name in enumerate(MEAS_CHANNELS)
            if self._use[c]
        ]
        self._p0 = np.array(
            [
                2e-6,
                1e-3,
                1e-4,
                5e-3,
                c.init_sigma_f_r,
                c.init_sigma_p_sr,
                c.init_sigma_c_lk,
                c.init_sigma_i_b,
            ]
        )
        self.ukf = BatchUKF(_NX, alpha=c.alpha, beta=c.beta, kappa=c.kappa)
        self._prm = er.param_vector(self.rp)
        a = c.alarms
        self._cst = np.array(
            [
                self.rp.h_max,
                c.c_lk_max / self.scale[6],
                self.rp.p_vap / self.scale[5],
                b.p_sr_rated / self.scale[5],
                c.nis_tau_s,
                c.nis_reinit,
                b.c_lk,
                b.p_sr_rated,
                c.arm_s,
                a.leak_raise,
                a.leak_clear,
                a.supply_raise,
                a.supply_clear,
                a.hold_s,
                a.leak_max_sigma,
                a.supply_max_sigma,
                c.c_lk_gate_v / self.scale[3],
                (self.rp.x_u if self.rp.x_u > 0 else math.inf) / self.scale[0],
                c.c_lk_gate_nis,
            ]
        )  # layout: the _C_* constants
        self._ws = workspace(_NX, 5)
        self.ids: dict[str, int] = {}
        self._rows: list | None = None
        self._alloc(capacity)

    # -- storage -------------------------------------------------------------------------
    def _alloc(self, cap: int) -> None:
        n = _NX
        self.x = np.zeros((cap, n))  # scaled filter state
        self.P = np.zeros((cap, n, n))
        self.ol = np.zeros((cap, n))  # SI open-loop (parallel) model state
        self.t_last = np.full(cap, -np.inf)
        self.i_last = np.zeros(cap)
        self.nis_avg = np.zeros(cap)
        self.t_init = np.zeros(cap)
        self.alarm = np.zeros((cap, len(ALARM_KINDS)), bool)
        self.pending = np.full((cap, len(ALARM_KINDS)), np.nan)  # since when a change is due
        self.counters: list[dict[str, int]] = [dict.fromkeys(_COUNTERS, 0) for _ in range(cap)]
        self.events_log: list[list[AlarmEvent]] = [[] for _ in range(cap)]

    _ARRAYS = ("x", "P", "ol", "t_last", "i_last", "nis_avg", "t_init", "alarm", "pending")

    def _grow(self) -> None:
        n_old = len(self.x)
        old = {a: getattr(self, a) for a in self._ARRAYS}
        counters = self.counters
        events = self.events_log
        self._alloc(2 * n_old)
        for a, v in old.items():
            getattr(self, a)[:n_old] = v
        self.counters[:n_old] = counters
        self.events_log[:n_old] = events

    def _key_of(self, k: int) -> str:
        for key, v in self.ids.items():
            if v == k:
                return key
        return "?"

    def _index(self, key: str) -> int:
        k = self.ids.get(key)
        if k is None:
            k = len(self.ids)
            if k >= len(self.x):
                self._grow()
            self.ids[key] = k
        return k

    # -- public --------------------------------------------------------------------------
    def counters_of(self, key: str) -> dict[str, int]:
        """Sample counters of actuator ``key`` (accepted, skipped_nan, skipped_time, ...)."""
        return self.counters[self.ids[key]]

    def update_many(self, samples: Sequence[tuple[str, Mapping]]) -> list[MonitorOutput | None]:
        """Process samples (actuator id, sample) in order; the result equals feeding them one
        by one (None for a skipped sample)."""
        if len(samples) <= 2:  # as update_rows: the per-round path, dicts built directly
            return self.update_many_rounds(samples)
        out: list[MonitorOutput | None] = [None] * len(samples)
        rows = self.update_rows(samples)
        est_l, res_l, h_l, t_l = (
            rows.est.tolist(),
            rows.res.tolist(),
            rows.health.tolist(),
            rows.t.tolist(),
        )
        for r, slot in enumerate(rows.index.tolist()):
            out[slot] = MonitorOutput(
                t=t_l[r],
                est=dict(zip(_EST_KEYS, est_l[r], strict=False)),
                res=dict(zip(_RES_KEYS, res_l[r], strict=False)),
                health=dict(zip(_HEALTH_KEYS, h_l[r], strict=False)),
                events=rows.events[r],
            )
        return out

    def update_rows(self, samples: Sequence[tuple[str, Mapping]]) -> BankRows:
        """As ``update_many`` (same numbers) but the outputs stay numpy rows (``BankRows``):
        no per-sample dicts, for a fleet that logs or publishes arrays. The whole block is
        parsed with numpy and run through two compiled loops (``_block_steps``, which returns
        to Python only for a (re-)initialisation, then ``_block_rows``). A batch of one or two samples takes the
        per-round path (same numbers, less fixed cost per call)."""
        if len(samples) <= 2:
            return self.update_rows_rounds(samples)
        return self._run_block(samples)

    def index_of(self, key: str) -> int:
        """Row of actuator ``key`` in the bank (created on first use); for ``update_arrays``."""
        return self._index(key)

    def update_arrays(self, ks: NDArray, t: NDArray, channels: NDArray) -> BankRows:
        """``update_rows`` for samples already in arrays (no dicts): actuator rows ``ks`` (n,)
        from ``index_of``, sample times ``t`` (n,) [s] and ``channels`` (n, 7) in the wire
        order of ``service.messages.CHANNELS`` (x_cmd, i, x_s, x_j, p1, p2, p_sr; SI), NaN
        where a channel is absent. Same numbers as ``update_rows`` on the equivalent dicts
        (with None for the NaNs); ``BankRows.index`` refers to positions in these arrays."""
        sb = self.step_arrays(ks, t, channels)
        return _empty_rows() if sb is None else self.rows_of(sb)

    def step_arrays(self, ks: NDArray, t: NDArray, channels: NDArray) -> StepBlock | None:
        """First half of ``update_arrays`` (same arguments): the filter steps, parallel model
        and counters; None for an empty block. ``rows_of`` makes the output rows and alarms.
        The halves touch disjoint state, so a pipeline may step block b + 1 in one thread
        while another makes the rows of block b (both compiled loops release the GIL), as
        long as ``rows_of`` takes the blocks in the order they were stepped and ``index_of``
        does not add an actuator meanwhile."""
        ks = np.ascontiguousarray(ks, np.int64)
        n = len(ks)
        if n == 0:
            return None
        if ks.min() < 0 or ks.max() >= len(self.ids):
            raise ValueError("update_arrays: ks must be rows returned by index_of")
        ch = np.ascontiguousarray(channels, float)
        t = np.ascontiguousarray(t, float)
        if ch.shape != (n, 7) or t.shape != (n,):
            raise ValueError(f"update_arrays: expected t ({n},) and channels ({n}, 7)")
        vals = np.empty((n, 8))
        vals[:, 0] = t
        vals[:, 1:6] = ch[:, 2:7]  # x_s, x_j, p1, p2, p_sr
        vals[:, 6] = ch[:, 1]  # i
        vals[:, 7] = ch[:, 0]  # x_cmd
        return self._steps(*self._inputs(ks, vals, ~np.isnan(vals)))

    def rows_of(self, sb: StepBlock) -> BankRows:
        """Second half of ``update_arrays``: the output rows of a ``step_arrays`` block and
        the alarms (hysteresis, persistence), with the re-initialisation events."""
        return self._rows_of(sb)

    # -- reference path: one kernel call per round of at most one sample per actuator ---
    def update_many_rounds(
        self, samples: Sequence[tuple[str, Mapping]]
    ) -> list[MonitorOutput | None]:
        """``update_many`` by rounds (the n-th sample of each actuator goes into round n);
        the reference the block path is tested against (``tests/test_monitor_block.py``)."""
        out: list[MonitorOutput | None] = [None] * len(samples)
        self._run_rounds(samples, out)
        return out

    def update_rows_rounds(self, samples: Sequence[tuple[str, Mapping]]) -> BankRows:
        """``update_rows`` by rounds (reference path, see ``update_many_rounds``)."""
        self._rows = []
        try:
            self._run_rounds(samples, None)
            parts = self._rows
        finally:
            self._rows = None
        if not parts:
            return _empty_rows()
        idx = np.concatenate([np.asarray(p[0], int) for p in parts])
        order = np.argsort(idx, kind="stable")
        evs = [e for p in parts for e in p[5]]
        return BankRows(
            index=idx[order],
            t=np.concatenate([p[1] for p in parts])[order],
            est=np.concatenate([p[2] for p in parts])[order],
            res=np.concatenate([p[3] for p in parts])[order],
            health=np.concatenate([p[4] for p in parts])[order],
            events=RowEvents.of([evs[j] for j in order]),
        )

    # -- block path ----------------------------------------------------------------------
    def _parse_block(self, samples: Sequence[tuple[str, Mapping]]):
        """Vectorised ``_parse`` of every sample: (ks, t, z (scaled), mask, cand, i_m, x_c)
        with NaN for an absent or bad i / x_cmd; counts bad_channel and skipped_nan (the
        time checks are sequential and done in ``_block_steps``)."""
        n = len(samples)
        ids = self.ids
        kl = []
        vl = []
        for key, s in samples:
            k = ids.get(key)
            if k is None:
                k = self._index(key)
            kl.append(k)
            g = s.get
            vl.append((g("t"), g("x_s"), g("x_j"), g("p1"), g("p2"), g("p_sr"), g("i"), g("x_cmd")))
        ks = np.array(kl, np.int64)
        fast = False
        if set(map(type, [v for row in vl for v in row])) <= _PLAIN:
            try:
                obj = np.empty((n, 8), object)
                obj[:] = vl
                present = obj != None  # noqa: E711 (element-wise)
                vals = obj.astype(float)
                fast = True
            except (TypeError, ValueError, OverflowError):
                fast = False
        if not fast:  # anything else goes through _f, value by value, as _parse does
            present = np.zeros((n, 8), bool)
            vals = np.full((n, 8), math.nan)
            for j, row in enumerate(vl):
                for c, v in enumerate(row):
                    if v is not None:
                        present[j, c] = True
                        fv = _f(v)
                        if fv is not None:
                            vals[j, c] = fv
        return self._inputs(ks, vals, present)

    def _inputs(self, ks: NDArray, vals: NDArray, present: NDArray):
        """Filter inputs of a block from ``vals`` (n, 8) in the order t, x_s, x_j, p1, p2,
        p_sr, i, x_cmd and ``present`` (n, 8): a present non-finite value counts as
        bad_channel, a sample with no usable value as skipped_nan (``_prepare_inputs``)."""
        cnt = np.zeros((len(self.x), 2), np.int64)
        t, z, mask, cand, i_m, x_c = _prepare_inputs(
            ks, np.ascontiguousarray(vals), np.ascontiguousarray(present), self._use,
            self._zscale, cnt,
        )  # fmt: skip
        for k in np.flatnonzero(cnt.any(1)).tolist():
            c = self.counters[k]
            c["bad_channel"] += int(cnt[k, 0])
            c["skipped_nan"] += int(cnt[k, 1])
        return ks, t, z, mask, cand, i_m, x_c

    def _run_block(self, samples: Sequence[tuple[str, Mapping]]) -> BankRows:
        if len(samples) == 0:
            return _empty_rows()
        return self._run_inputs(*self._parse_block(samples))

    def _run_inputs(self, ks, t, z, mask, cand, i_m, x_c) -> BankRows:
        return self._rows_of(self._steps(ks, t, z, mask, cand, i_m, x_c))

    def _steps(self, ks, t, z, mask, cand, i_m, x_c) -> StepBlock:
        n = len(ks)
        nx = _NX
        y = np.zeros((n, 5))
        nis = np.zeros(n)
        nis_avg = np.zeros(n)
        acc = np.zeros(n, np.bool_)
        snap = (np.empty((n, nx)), np.empty((n, nx)), np.empty((n, nx)), np.empty(n),
                np.empty(n))  # fmt: skip
        cnt = np.zeros((len(self.x), 3), np.int64)  # skipped_time, missing_channel, accepted
        extra: dict[int, list[AlarmEvent]] = {}
        j, emit = 0, False
        while True:
            j, code = _block_steps(
                j, emit, ks, t, z, mask, cand, i_m, x_c, self.x, self.P, self.ol, self.t_last,
                self.i_last, self.nis_avg, self.t_init, self._q, self.R, self.scale,
                self._zscale, self.ukf.w.Wm, self.ukf.w.Wc, self.ukf.w.c, self._prm, self._cst,
                self.config.max_gap_s, self._expect, self._ws, y, nis, nis_avg, acc, *snap, cnt,
            )  # fmt: skip
            if code == 0:
                break
            k = int(ks[j])
            i_j = None if math.isnan(i_m[j]) else float(i_m[j])
            x_j = None if math.isnan(x_c[j]) else float(x_c[j])
            tj = float(t[j])
            if code == 3:  # first sample or gap: (re-)initialise from this sample
                if math.isfinite(self.t_last[k]):
                    self.counters[k]["gap"] += 1
                self._init_state(k, z[j], mask[j], i_j, x_j)
                self.t_last[k] = tj
                self.t_init[k] = tj
                self.i_last[k] = i_j if i_j is not None else 0.0
                self.counters[k]["accepted"] += 1
            else:  # 1: broken, 2: diverged (the step was done and counted)
                keep = self.x[k].copy()
                self._init_state(k, z[j], mask[j], i_j, x_j)
                if code == 2:  # keep the parameter estimates, restart the covariance
                    self.x[k, 4:] = keep[4:]
                y[j] = 0.0
                nis[j] = 0.0
                self.counters[k]["reinit"] += 1
                self.t_init[k] = tj
                value = float(nis_avg[j]) if math.isfinite(nis_avg[j]) else 0.0
                extra[j] = [AlarmEvent(tj, "reinit", "raised", value)]
                log.warning(
                    "monitor %s re-initialised at t=%.6f (%s, NIS/dof average %.3g)",
                    self._key_of(k), tj, "non-finite or not positive definite"
                    if code == 1 else "diverged", value,
                )  # fmt: skip
            emit = True
        for k in np.flatnonzero(cnt.any(1)).tolist():
            c = self.counters[k]
            c["skipped_time"] += int(cnt[k, 0])
            c["missing_channel"] += int(cnt[k, 1])
            c["accepted"] += int(cnt[k, 2])
        return StepBlock(ks, t, z, mask, y, nis, acc, snap, extra)

    def _rows_of(self, sb: StepBlock) -> BankRows:
        ks, t = sb.ks, sb.t
        n = len(ks)
        est = np.zeros((n, len(_EST_KEYS)))
        res = np.zeros((n, len(_RES_KEYS)))
        health = np.zeros((n, len(_HEALTH_KEYS)))
        fire = np.zeros((n, len(ALARM_KINDS)), np.int64)
        _block_rows(
            ks, sb.acc, *sb.snap, self.scale, self._zscale, self._prm, sb.z, sb.mask, sb.y,
            sb.nis, t, self.alarm, self.pending, self._cst, est, res, health, fire,
        )  # fmt: skip
        extra = sb.extra
        sel = np.flatnonzero(sb.acc)
        at: dict[int, list[AlarmEvent]] = {}
        fired = fire.any(1)
        if extra or fired.any():
            row_of = np.full(n, -1, np.int64)
            row_of[sel] = np.arange(len(sel))
            for j in sorted(set(extra) | set(np.flatnonzero(fired).tolist())):
                ev = at.setdefault(int(row_of[j]), [])
                ev.extend(extra.get(j, ()))
                for a in range(len(ALARM_KINDS)):
                    if fire[j, a]:
                        state = "raised" if fire[j, a] == 1 else "cleared"
                        ev.append(AlarmEvent(float(t[j]), ALARM_KINDS[a], state,
                                             float(health[j, a])))  # fmt: skip
                self.events_log[int(ks[j])].extend(ev)
        return BankRows(
            index=sel,
            t=t[sel],
            est=est[sel],
            res=res[sel],
            health=health[sel],
            events=RowEvents(len(sel), at),
        )

    def _run_rounds(self, samples, out) -> None:
        seen: dict[str, int] = {}
        rounds: list[list[int]] = []
        for j, (key, _) in enumerate(samples):
            r = seen.get(key, 0)
            seen[key] = r + 1
            if r == len(rounds):
                rounds.append([])
            rounds[r].append(j)
        for r in rounds:
            self._round([samples[j] for j in r], r, out)

    # -- core ----------------------------------------------------------------------------
    def _parse(self, k: int, s: Mapping):
        """(t, z list (scaled), mask list, i, x_cmd) or None (counted)."""
        get = s.get
        t = get("t")
        if type(t) is not float or t - t != 0.0:
            t = _f(t)
            if t is None:
                self.counters[k]["skipped_nan"] += 1
                return None
        z = [0.0] * 5
        mask = [False] * 5
        bad = 0
        for c, name, zs in self._chan:
            v = get(name)
            if v is None:
                continue
            if type(v) is not float or v - v != 0.0:
                v = _f(v)
                if v is None:
                    bad += 1
                    continue
            z[c] = v / zs
            mask[c] = True
        i = get("i")
        if i is not None and (type(i) is not float or i - i != 0.0):
            i = _f(i)
            if i is None:
                bad += 1
        x_cmd = get("x_cmd")
        if x_cmd is not None and (type(x_cmd) is not float or x_cmd - x_cmd != 0.0):
            x_cmd = _f(x_cmd)
            if x_cmd is None:
                bad += 1
        if bad:
            self.counters[k]["bad_channel"] += bad
        if i is None and x_cmd is None and not any(mask):
            self.counters[k]["skipped_nan"] += 1
            return None
        if t <= self.t_last[k]:
            self.counters[k]["skipped_time"] += 1
            return None
        for c in self._expect_idx:
            if not mask[c]:
                self.counters[k]["missing_channel"] += 1
        return t, z, mask, i, x_cmd

    def _init_state(self, k: int, z: NDArray, mask: NDArray, i, x_cmd) -> None:
        b, rp = self.baseline, self.rp
        sc = self._zscale
        x_s = z[0] * sc[0] if mask[0] else (b.k_sv * i if i is not None else 0.0)
        x_j = z[1] * sc[1] if mask[1] else (x_cmd if x_cmd is not None else 0.0)
        p_sr = b.p_sr_rated
        if mask[4]:
            p_sr = z[4] * sc[4]
        elif mask[2] and mask[3]:
            p_sr = (z[2] + z[3]) * sc[2] - 2 * b.p_r
        p_sr = float(np.clip(p_sr, rp.p_vap, b.p_sr_rated))
        f_r = 0.0
        if mask[2] and mask[3]:
            f_r = (z[2] - z[3]) * sc[2] * b.area
        xs = np.array([x_s, 0.0, x_j, 0.0, f_r, p_sr, b.c_lk, 0.0])
        self.x[k] = xs / self.scale
        self.P[k] = np.diag((self._p0 / self.scale) ** 2)
        self.ol[k] = xs
        self.ol[k, 5], self.ol[k, 6] = b.p_sr_rated, b.c_lk
        self.nis_avg[k] = 0.0

    def _fx(self, sig_si: NDArray, i: NDArray, dt: NDArray) -> NDArray:
        """Numpy process model on SI points (B, K, 7) (reference path, used by tests)."""
        ev = sig_si.copy()
        ev[..., 6] = np.maximum(ev[..., 6], 0.0)
        ev[..., 5] = np.maximum(ev[..., 5], self.rp.p_vap)
        n_sub = max(1, int(math.ceil(float(dt.max()) / self.rp.h_max - 1e-9)))
        out = er.step(ev, i, dt[:, None], self.rp, n_sub)
        out[..., 5:] = sig_si[..., 5:]
        return out

    def _round(self, items: list[tuple[str, Mapping]], slots: list[int], out: list) -> None:
        cfg = self.config
        idx, parsed, slot_of = [], [], []
        for (key, s), slot in zip(items, slots, strict=True):
            k = self._index(key)
            p = self._parse(k, s)
            if p is None:
                continue
            t = p[0]
            if not math.isfinite(self.t_last[k]) or t - self.t_last[k] > cfg.max_gap_s:
                if math.isfinite(self.t_last[k]):
                    self.counters[k]["gap"] += 1
                z1, m1 = np.array([p[1]]), np.array([p[2]], bool)
                self._init_state(k, z1[0], m1[0], p[3], p[4])
                self.t_last[k] = t
                self.t_init[k] = t
                self.i_last[k] = p[3] if p[3] is not None else 0.0
                self.counters[k]["accepted"] += 1
                self._outputs(
                    np.array([k]), np.array([t]), z1, m1, np.zeros((1, 5)), np.zeros(1), [[]],
                    [slot], out,
                )  # fmt: skip
                continue
            idx.append(k)
            parsed.append(p)
            slot_of.append(slot)
        if not idx:
            return
        ks = np.array(idx)
        B = len(ks)
        t = np.array([p[0] for p in parsed])
        z = np.array([p[1] for p in parsed])
        mask = np.array([p[2] for p in parsed], bool)
        nan = math.nan
        i_m = np.array([nan if p[3] is None else p[3] for p in parsed])
        x_c = np.array([nan if p[4] is None else p[4] for p in parsed])
        y = np.zeros((B, 5))
        nis = np.zeros(B)
        nis_avg = np.zeros(B)
        flag = np.zeros(B, np.int64)
        _bank_step(
            ks, t, z, mask, i_m, x_c, self.x, self.P, self.ol, self.t_last, self.i_last,
            self.nis_avg, self._q, self.R, self.scale, self._zscale, self.ukf.w.Wm,
            self.ukf.w.Wc, self.ukf.w.c, self._prm, self._cst, self._ws, y, nis, nis_avg, flag,
        )  # fmt: skip
        bad, diverged = flag == 1, flag == 2
        evs: list[list[AlarmEvent]] = [[] for _ in range(B)]
        for j in np.flatnonzero(bad | diverged):
            k = int(ks[j])
            keep = self.x[k].copy()
            self._init_state(k, z[j], mask[j], parsed[j][3], parsed[j][4])
            if not bad[j]:  # keep the parameter estimates, restart the covariance
                self.x[k, 4:] = keep[4:]
            y[j] = 0.0
            nis[j] = 0.0
            self.counters[k]["reinit"] += 1
            self.t_init[k] = t[j]
            value = float(nis_avg[j]) if math.isfinite(nis_avg[j]) else 0.0
            evs[j].append(AlarmEvent(float(t[j]), "reinit", "raised", value))
            log.warning(
                "monitor %s re-initialised at t=%.6f (%s, NIS/dof average %.3g)",
                self._key_of(k), float(t[j]), "non-finite or not positive definite"
                if bad[j] else "diverged", value,
            )  # fmt: skip
        for k in ks:
            self.counters[k]["accepted"] += 1
        self._outputs(ks, t, z, mask, y, nis, evs, slot_of, out)

    def _outputs(self, ks, t, z, mask, y, nis, evs, slots, out) -> None:
        n = len(ks)
        # zeros, not empty: every column is written by _output_rows, but a row must never
        # expose uninitialised memory should a column ever be skipped
        est = np.zeros((n, len(_EST_KEYS)))
        res = np.zeros((n, len(_RES_KEYS)))
        health = np.zeros((n, len(_HEALTH_KEYS)))
        fire = np.zeros((n, len(ALARM_KINDS)), np.int64)
        _output_rows(
            self.x, np.diagonal(self.P, axis1=1, axis2=2).copy(), self.ol, ks, self.scale, self._zscale, self._prm, z, mask, y, nis,
            t, self.t_init, self.nis_avg, self.alarm, self.pending, self._cst, est, res,
            health, fire,
        )  # fmt: skip
        for j, a in zip(*np.nonzero(fire), strict=True):
            state = "raised" if fire[j, a] == 1 else "cleared"
            evs[j].append(AlarmEvent(float(t[j]), ALARM_KINDS[a], state, float(health[j, a])))
        for j in np.flatnonzero([bool(e) for e in evs]):
            self.events_log[int(ks[j])].extend(evs[j])
        if self._rows is not None:  # update_rows: keep the arrays
            self._rows.append((slots, t, est, res, health, evs))
            return
        est_l, res_l, h_l, t_l = est.tolist(), res.tolist(), health.tolist(), t.tolist()
        for j, slot in enumerate(slots):
            out[slot] = MonitorOutput(
                t=t_l[j],
                est=dict(zip(_EST_KEYS, est_l[j], strict=False)),
                res=dict(zip(_RES_KEYS, res_l[j], strict=False)),
                health=dict(zip(_HEALTH_KEYS, h_l[j], strict=False)),
                events=evs[j],
            )


_EST_KEYS = tuple([k for n in er.STATE_NAMES for k in (n, n + "_sigma")] + ["p12", "c_lk_increase"])
_HEALTH_KEYS = (
    ("leak_ratio", "supply_ratio") + tuple(f"alarm_{k}" for k in ALARM_KINDS) + ("nis_avg",)
)
_RES_KEYS = tuple(
    [f"innov_{c}" for c in MEAS_CHANNELS] + ["nis", "nis_dof"] + [f"ol_{c}" for c in MEAS_CHANNELS]
)


(
    _C_H_MAX,
    _C_C_LK_MAX,
    _C_P_VAP,
    _C_P_SR_MAX,
    _C_NIS_TAU,
    _C_NIS_REINIT,
    _C_C_LK0,
    _C_P_RATED,
    _C_ARM,
    _C_LEAK_RAISE,
    _C_LEAK_CLEAR,
    _C_SUP_RAISE,
    _C_SUP_CLEAR,
    _C_HOLD,
    _C_LEAK_SIG,
    _C_SUP_SIG,
    _C_GATE_V,
    _C_GATE_XS,
    _C_GATE_NIS,
) = range(19)


@njit(cache=True, inline="always")
def _step_one(
    j, k, t, z, mask, i_m, x_c, X, PP, OL, T_LAST, I_LAST, NIS_AVG, q, R, scale, zscale, Wm,
    Wc, c, prm, cst, ws, y, nis, nis_avg, coef, tmp,
):  # fmt: skip
    """Sample j of actuator k (in place on the bank arrays): inputs (measured current, else
    the ECU law on x_cmd), UKF step, parallel model, constraints, NIS average. Returns 0 ok,
    1 broken (non-finite / not positive definite), 2 diverged (NIS average)."""
    n = X.shape[1]
    k_p, i_max = prm[er.K_K_P], prm[er.K_I_MAX]
    dt = t[j] - T_LAST[k]
    n_sub = max(1, int(math.ceil(dt / cst[_C_H_MAX] - 1e-9)))
    if not math.isnan(i_m[j]):
        i_f = i_m[j]
    elif not math.isnan(x_c[j]):
        i_f = min(max(k_p * (x_c[j] - X[k, 2] * scale[2]), -i_max), i_max)
    else:
        i_f = I_LAST[k]
    i_ol = i_f if math.isnan(x_c[j]) else min(max(k_p * (x_c[j] - OL[k, 2]), -i_max), i_max)
    I_LAST[k] = i_f
    # observability gate: C_Lk only from the valve's linear region at low speed
    gate = abs(X[k, 3]) > cst[_C_GATE_V] or abs(X[k, 0]) > cst[_C_GATE_XS]
    gate = gate or NIS_AVG[k] > cst[_C_GATE_NIS]
    c_prior, p_prior = X[k, 6], PP[k, 6, 6]
    nis_j, st = ukf_one(
        X[k], PP[k], z[j], mask[j], i_f, dt, n_sub, q, R, scale, zscale, Wm, Wc, c, prm,
        y[j], ws,
    )  # fmt: skip
    if gate:  # Schmidt (consider) update of C_Lk: prior mean and variance, cross terms kept
        X[k, 6] = c_prior
        PP[k, 6, 6] = p_prior + q[6] * dt
    nis[j] = nis_j
    # the parallel (open-loop) model, driven by the command, with the estimated load
    OL[k, 4] = X[k, 4] * scale[4]
    h = dt / n_sub
    spool_coef_nb(h, prm, coef)
    step_core_nb(OL[k], i_ol, h, n_sub, prm, coef, tmp)
    for r in range(n):
        OL[k, r] = tmp[r]
    # constraints: C_Lk >= 0, P_vap <= P_SR <= rated
    X[k, 6] = min(max(X[k, 6], 0.0), cst[_C_C_LK_MAX])
    X[k, 5] = min(max(X[k, 5], cst[_C_P_VAP]), cst[_C_P_SR_MAX])
    dof = 0.0
    for r in range(mask.shape[1]):
        if mask[j, r]:
            dof += 1.0
    a = 1.0 - math.exp(-dt / cst[_C_NIS_TAU])
    avg = NIS_AVG[k] + a * (nis_j / max(dof, 1.0) - NIS_AVG[k])
    nis_avg[j] = avg
    ok = st != 2 and math.isfinite(avg)
    for r in range(n):
        if not math.isfinite(X[k, r]):
            ok = False
        for s_ in range(n):
            if not math.isfinite(PP[k, r, s_]):
                ok = False
    T_LAST[k] = t[j]
    if ok:
        NIS_AVG[k] = avg
        return 2 if avg > cst[_C_NIS_REINIT] else 0
    NIS_AVG[k] = 0.0
    return 1


@njit(cache=True, inline="always")
def _row_one(
    j, kk, k, X, PD, OL, T_INIT, NIS_AVG, scale, zscale, prm, z, mask, y, nis, t, ALARM,
    PENDING, cst, est, res, health, fire, xs, zo,
):  # fmt: skip
    """Flat output row j of actuator k (est: (state, sigma) pairs, P12, C_Lk increase; res:
    innovations, NIS, dof, open-loop residuals = measured minus parallel model; health: leak
    and supply ratios, alarm states, NIS average) and the alarms with hysteresis, persistence
    and the sigma gate (fire: 1 raised, 2 cleared this sample). The filter state is row kk of
    X, PD (the diagonal of P), OL, T_INIT and NIS_AVG: the bank's row k, or the snapshot of
    sample j taken by ``_block_steps``; the alarm state is the bank's row k."""
    n = X.shape[1]
    m = z.shape[1]
    c_lk0, p_rated = cst[_C_C_LK0], cst[_C_P_RATED]
    for r in range(n):
        xs[r] = X[kk, r] * scale[r]
        est[j, 2 * r] = xs[r]
        est[j, 2 * r + 1] = math.sqrt(max(PD[kk, r], 0.0)) * scale[r]
    measure_nb(xs, prm, zo)
    est[j, 2 * n] = zo[2] - zo[3]  # P12
    est[j, 2 * n + 1] = xs[6] - c_lk0
    measure_nb(OL[kk], prm, zo)
    dof = 0.0
    for r in range(m):
        res[j, r] = y[j, r] * zscale[r]
        if mask[j, r]:
            dof += 1.0
            res[j, 7 + r] = z[j, r] * zscale[r] - zo[r]
        else:
            res[j, 7 + r] = 0.0
    res[j, 5] = nis[j]
    res[j, 6] = dof
    lr = xs[6] / c_lk0 if c_lk0 > 0 else 0.0
    sr = xs[5] / p_rated
    sd_l = est[j, 13] / c_lk0 if c_lk0 > 0 else 0.0
    sd_s = est[j, 11] / p_rated
    armed = t[j] - T_INIT[kk] >= cst[_C_ARM]
    for a in range(2):
        on = ALARM[k, a]
        if a == 0:
            want = (
                lr <= cst[_C_LEAK_CLEAR]
                if on
                else (lr >= cst[_C_LEAK_RAISE] and sd_l < cst[_C_LEAK_SIG])
            )
        else:
            want = (
                sr >= cst[_C_SUP_CLEAR]
                if on
                else (sr <= cst[_C_SUP_RAISE] and sd_s < cst[_C_SUP_SIG])
            )
        fire[j, a] = 0
        if want and armed:
            if math.isnan(PENDING[k, a]):
                PENDING[k, a] = t[j]
            if t[j] - PENDING[k, a] >= cst[_C_HOLD] - 1e-12:
                ALARM[k, a] = not on
                PENDING[k, a] = math.nan
                fire[j, a] = 2 if on else 1
        else:
            PENDING[k, a] = math.nan
    health[j, 0] = lr
    health[j, 1] = sr
    health[j, 2] = 1.0 if ALARM[k, 0] else 0.0
    health[j, 3] = 1.0 if ALARM[k, 1] else 0.0
    health[j, 4] = NIS_AVG[kk]


@njit(cache=True)
def _bank_step(
    ks, t, z, mask, i_m, x_c, X, PP, OL, T_LAST, I_LAST, NIS_AVG, q, R, scale, zscale, Wm, Wc,
    c, prm, cst, ws, y, nis, nis_avg, flag,
):  # fmt: skip
    """One sample for each actuator ks[j] through ``_step_one``; flag[j] its return code."""
    ks, t, z, mask, i_m, x_c, X, PP, OL, T_LAST, I_LAST, NIS_AVG = borrowed_all(
        (ks, t, z, mask, i_m, x_c, X, PP, OL, T_LAST, I_LAST, NIS_AVG)
    )
    q, R, scale, zscale, Wm, Wc, prm, cst, y, nis, nis_avg, flag = borrowed_all(
        (q, R, scale, zscale, Wm, Wc, prm, cst, y, nis, nis_avg, flag)
    )
    ws = borrowed_all(ws)
    coef = np.empty(4)
    tmp = np.empty(X.shape[1])
    for j in range(ks.shape[0]):
        flag[j] = _step_one(
            j, ks[j], t, z, mask, i_m, x_c, X, PP, OL, T_LAST, I_LAST, NIS_AVG, q, R, scale,
            zscale, Wm, Wc, c, prm, cst, ws, y, nis, nis_avg, coef, tmp,
        )  # fmt: skip


@njit(cache=True)
def _output_rows(
    X, PD, OL, ks, scale, zscale, prm, z, mask, y, nis, t, T_INIT, NIS_AVG, ALARM, PENDING, cst,
    est, res, health, fire,
):  # fmt: skip
    """The output row of each actuator ks[j] through ``_row_one`` (PD: diagonals of P)."""
    X, PD, OL, ks, scale, zscale, prm, z, mask, y, nis, t = borrowed_all(
        (X, PD, OL, ks, scale, zscale, prm, z, mask, y, nis, t)
    )
    T_INIT, NIS_AVG, ALARM, PENDING, cst, est, res, health, fire = borrowed_all(
        (T_INIT, NIS_AVG, ALARM, PENDING, cst, est, res, health, fire)
    )
    xs = np.empty(X.shape[1])
    zo = np.empty(z.shape[1])
    for j in range(ks.shape[0]):
        k = ks[j]
        _row_one(
            j, k, k, X, PD, OL, T_INIT, NIS_AVG, scale, zscale, prm, z, mask, y, nis, t, ALARM,
            PENDING, cst, est, res, health, fire, xs, zo,
        )  # fmt: skip


@njit(cache=True, nogil=True)
def _prepare_inputs(ks, vals, present, use, zscale, cnt):
    """``MonitorBank._inputs`` compiled (numpy's per-call cost on short blocks was a tenth of
    the filter step): vals (n, 8) as t, x_s, x_j, p1, p2, p_sr, i, x_cmd, present (n, 8) ->
    (t (0 where not usable), z (scaled, 0 where masked), mask, cand, i_m, x_c (NaN where not
    usable)); cnt[k] += bad_channel (present and not finite, in a sample with a usable time),
    skipped_nan (no usable value)."""
    n = ks.shape[0]
    m = zscale.shape[0]
    t_out = np.empty(n)
    z = np.empty((n, m))
    mask = np.empty((n, m), np.bool_)
    cand = np.empty(n, np.bool_)
    i_m = np.empty(n)
    x_c = np.empty(n)
    for j in range(n):
        t_ok = present[j, 0] and math.isfinite(vals[j, 0])
        n_bad = 0
        any_m = False
        for r in range(m):
            v = vals[j, 1 + r]
            fin = math.isfinite(v)
            ok = present[j, 1 + r] and fin and use[r]
            mask[j, r] = ok
            z[j, r] = v / zscale[r] if ok else 0.0
            any_m = any_m or ok
            if present[j, 1 + r] and not fin and use[r]:
                n_bad += 1
        vi, vx = vals[j, 1 + m], vals[j, 2 + m]
        i_ok = present[j, 1 + m] and math.isfinite(vi)
        x_ok = present[j, 2 + m] and math.isfinite(vx)
        i_m[j] = vi if i_ok else math.nan
        x_c[j] = vx if x_ok else math.nan
        if present[j, 1 + m] and not i_ok:
            n_bad += 1
        if present[j, 2 + m] and not x_ok:
            n_bad += 1
        cand[j] = t_ok and (i_ok or x_ok or any_m)
        t_out[j] = vals[j, 0] if t_ok else 0.0
        if t_ok:
            cnt[ks[j], 0] += n_bad
        if not cand[j]:
            cnt[ks[j], 1] += 1
    return t_out, z, mask, cand, i_m, x_c


@njit(cache=True, nogil=True)  # other threads (receivers, loggers) run meanwhile
def _block_steps(
    j0, emit0, ks, t, z, mask, cand, i_m, x_c, X, PP, OL, T_LAST, I_LAST, NIS_AVG, T_INIT, q,
    R, scale, zscale, Wm, Wc, c, prm, cst, max_gap, expect, ws, y, nis, nis_avg, acc, SX, SPD,
    SOL, STI, SNA, cnt,
):  # fmt: skip
    """The samples j0.. of a block in order, each through the time checks and ``_step_one``
    (the code of the per-round path, so the same bits); after its step, the state a sample's
    output row is made of (X, diagonal of P, OL, T_INIT, NIS_AVG of its actuator) is copied
    into row j of SX, SPD, SOL, STI, SNA for ``_block_rows``. Returns (j, code): code 0 when
    done; 3 when sample j needs a (re-)initialisation (first sample or gap; not stepped), 1/2
    when its step broke/diverged. The caller re-initialises and resumes with (j,
    emit0=True), which takes sample j's snapshot without stepping it. acc[j]: sample j has an
    output row; cnt[k]: skipped_time, missing_channel, accepted (stepped samples only)."""
    # every array argument through borrowed_all (see service.ukf): the inlined _step_one takes
    # about 30 arrays, which numba would otherwise reference-count with atomic operations at
    # every sample (about a fifth of the step)
    ks, t, z, mask, cand, i_m, x_c, X, PP, OL, T_LAST, I_LAST, NIS_AVG, T_INIT = borrowed_all(
        (ks, t, z, mask, cand, i_m, x_c, X, PP, OL, T_LAST, I_LAST, NIS_AVG, T_INIT)
    )
    q, R, scale, zscale, Wm, Wc, prm, cst, expect, y, nis, nis_avg = borrowed_all(
        (q, R, scale, zscale, Wm, Wc, prm, cst, expect, y, nis, nis_avg)
    )
    acc, SX, SPD, SOL, STI, SNA, cnt = borrowed_all((acc, SX, SPD, SOL, STI, SNA, cnt))
    ws = borrowed_all(ws)
    m = z.shape[1]
    n = X.shape[1]
    coef = np.empty(4)
    tmp = np.empty(n)
    for j in range(j0, ks.shape[0]):
        k = ks[j]
        if not (emit0 and j == j0):
            if not cand[j]:
                continue
            if t[j] <= T_LAST[k]:
                cnt[k, 0] += 1
                continue
            for r in range(m):
                if expect[r] and not mask[j, r]:
                    cnt[k, 1] += 1
            if not math.isfinite(T_LAST[k]) or t[j] - T_LAST[k] > max_gap:
                return j, 3
            cnt[k, 2] += 1
            code = _step_one(
                j, k, t, z, mask, i_m, x_c, X, PP, OL, T_LAST, I_LAST, NIS_AVG, q, R, scale,
                zscale, Wm, Wc, c, prm, cst, ws, y, nis, nis_avg, coef, tmp,
            )  # fmt: skip
            if code != 0:
                return j, code
        acc[j] = True
        for r in range(n):
            SX[j, r] = X[k, r]
            SPD[j, r] = PP[k, r, r]
            SOL[j, r] = OL[k, r]
        STI[j] = T_INIT[k]
        SNA[j] = NIS_AVG[k]
    return ks.shape[0], 0


@njit(cache=True, nogil=True)
def _block_rows(
    ks, acc, SX, SPD, SOL, STI, SNA, scale, zscale, prm, z, mask, y, nis, t, ALARM, PENDING,
    cst, est, res, health, fire,
):  # fmt: skip
    """The output rows of the samples with acc[j], in order, from their ``_block_steps``
    snapshots, through ``_row_one`` (alarms: the bank's ALARM, PENDING)."""
    ks, acc, SX, SPD, SOL, STI, SNA, scale, zscale, prm, z, mask = borrowed_all(
        (ks, acc, SX, SPD, SOL, STI, SNA, scale, zscale, prm, z, mask)
    )
    y, nis, t, ALARM, PENDING, cst, est, res, health, fire = borrowed_all(
        (y, nis, t, ALARM, PENDING, cst, est, res, health, fire)
    )
    xs = np.empty(SX.shape[1])
    zo = np.empty(z.shape[1])
    for j in range(ks.shape[0]):
        if acc[j]:
            _row_one(
                j, j, ks[j], SX, SPD, SOL, STI, SNA, scale, zscale, prm, z, mask, y, nis, t,
                ALARM, PENDING, cst, est, res, health, fire, xs, zo,
            )  # fmt: skip


class Monitor:
    """One actuator: a ``MonitorBank`` of one (same code path, same numbers)."""

    def __init__(self, config: MonitorConfig | None = None, baseline: Baseline | None = None):
        self._bank = MonitorBank(config, baseline, capacity=1)
        self._key = "_"
        self._bank._index(self._key)

    @property
    def config(self) -> MonitorConfig:
        return self._bank.config

    @property
    def baseline(self) -> Baseline:
        return self._bank.baseline

    @property
    def counters(self) -> dict[str, int]:
        """accepted, skipped_nan, skipped_time, missing_channel, bad_channel, reinit, gap."""
        return self._bank.counters_of(self._key)

    def update(self, sample: Mapping[str, float | None]) -> MonitorOutput | None:
        """Process one sample (keys t, x_cmd, i, x_s, x_j, p1, p2, p_sr; all but t optional);
        None when the sample is skipped (counted in ``counters``)."""
        return self._bank.update_many([(self._key, sample)])[0]


EST_KEYS, RES_KEYS, HEALTH_KEYS = _EST_KEYS, _RES_KEYS, _HEALTH_KEYS
