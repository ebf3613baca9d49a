"""Per-actuator health monitors: a UKF on the simplified (C-type) EHA model, no I/O.

Samples in, estimates out. ``MonitorBank`` serves many actuators in one vectorised update;
``Monitor`` is a ``MonitorBank`` of one, so both run the same code (``tests/test_monitor.py``
checks bit equality). Two paths give the same numbers: the block path (``update_arrays``,
``update_rows``; production), which runs a whole block through the compiled loops of
``service.monitor.kernels``, and the per-round path (``update_many_rounds``,
``update_rows_rounds``; the reference it is tested against), one kernel call per round of
at most one sample per actuator.

Filter state (SI; scaled internally so that the default noise settings need no tuning):
x_s, v_s, x_j, v_j (plant), f_r (external load), p_sr (supply), c_lk (internal leakage), i_b
(null bias), the last four as random walks. Inputs: servovalve current i (measured; else the
ECU law on x_cmd). Measurements: any of x_s, x_j, p1, p2, p_sr. See docs/estimation.md.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from models import eha_reduced as er
from models.channels import SENSORS as WIRE
from service.monitor.config import (
    MONITOR_MODELS,
    Baseline,
    MonitorConfig,
    check_baseline_model,
)
from service.monitor.kernels import (
    CARRY_GM,
    CARRY_GP,
    CARRY_I,
    CARRY_N,
    CARRY_P12,
    CARRY_T_FAST,
    IN_I,
    IN_T,
    IN_X_CMD,
    IN_Z,
    INPUT_COLUMNS,
    N_CARRY,
    N_CHANNELS,
    N_PENDING,
    POOL_CARRY,
    PREP_COUNTERS,
    S_C_LK,
    S_F_R,
    S_I_B,
    S_P_SR,
    STEP_BROKEN,
    STEP_COUNTERS,
    STEP_DIVERGED,
    STEP_INIT,
    STEP_OK,
    Z_P1,
    Z_P2,
    Z_P_SR,
    Z_X_J,
    Z_X_S,
    BankState,
    ModelRows,
    Rows,
    Samples,
    Sigma,
    Stepped,
    bank_step,
    block_rows,
    block_steps,
    output_rows,
    prepare_inputs,
)
from service.monitor.model_rows import by_name, model_vectors
from service.monitor.outputs import (
    ALARM_KINDS,
    COUNTERS,
    EST_KEYS,
    FIRE_RAISED,
    HEALTH_INDICATOR,
    HEALTH_KEYS,
    MEAS_CHANNELS,
    RES_KEYS,
    AlarmEvent,
    BankRows,
    MonitorOutput,
    RowEvents,
    StepBlock,
    empty_rows,
    log_reinit,
)
from service.monitor.ukf import BatchUKF, workspace
from service.monitor.usage import BankUsage

__all__ = ["MonitorBank", "Monitor"]

log = logging.getLogger(__name__)

_PLAIN = {float, int, type(None), np.float64}


_MIN_SPLIT = 64  # shorter blocks are stepped in the caller's thread alone


def _stepped(n: int, nx: int, cnt: NDArray) -> Stepped:
    """The outputs of ``block_steps`` for n samples of an nx-state filter (counters ``cnt``)."""
    return Stepped(np.zeros((n, N_CHANNELS)), np.zeros(n), np.zeros(n), np.zeros(n, np.bool_),
                   np.empty((n, nx)), np.empty((n, nx)), np.empty((n, nx)), np.empty(n),
                   np.empty(n), np.empty((n, 2)), cnt)  # fmt: skip


_PARAMS = slice(S_F_R, S_I_B + 1)  # the random-walk parameter states f_r, p_sr, c_lk, i_b
# columns of update_arrays' channels (the wire order, service.wire.messages.CHANNELS)
_WIRE_X_CMD, _WIRE_I, _WIRE_Z = WIRE.index("x_cmd"), WIRE.index("i"), WIRE.index(MEAS_CHANNELS[0])
assert WIRE[_WIRE_Z : _WIRE_Z + N_CHANNELS] == MEAS_CHANNELS


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
    """Monitors for many actuators advanced together in one vectorised UKF update.

    ``baseline`` is the default of every actuator; ``index_of(key, baseline)`` or
    ``set_baseline`` gives one its own; a baseline for another process model than the
    config's is refused (``BaselineModelError``). The baseline-dependent vectors (state and channel
    scales, Q, R, the model's parameter vector and the constants) are kept as one row per
    actuator, which the compiled kernels index by actuator, so actuators with different
    baselines still run in one batched update."""

    def __init__(
        self,
        config: MonitorConfig | None = None,
        baseline: Baseline | None = None,
        capacity: int = 8,
    ):
        self.config = config or MonitorConfig()
        if self.config.model not in MONITOR_MODELS:
            raise ValueError(
                f"unknown model {self.config.model!r}; expected one of {MONITOR_MODELS}"
            )
        self.baseline = baseline or Baseline.default(self.config.model)
        check_baseline_model(self.baseline, self.config.model)
        c = self.config
        # WH: models.eha_reduced_wh, the C-type states plus the chamber states p~1, p~2
        self.wh = c.model == "WH"
        v = model_vectors(c, self.baseline)  # the process model's factory
        self.rp = v.rp
        self._names = v.names
        self.nx = len(v.names)
        self.scale, self._zscale, self._q, self.R = v.scale, v.zscale, v.q, v.R
        self._prm, self._cst, self._p0 = v.prm, v.cst, v.p0
        self._use = np.zeros(N_CHANNELS, bool)
        self._use[[Z_X_S, Z_X_J, Z_P1, Z_P2, Z_P_SR] if c.channels == "full" else [Z_X_J]] = True
        # channels whose absence is counted (the supply transducer is optional)
        self._expect = self._use.copy()
        self._expect[Z_P_SR] = False
        self._expect_idx = [int(c) for c in np.flatnonzero(self._expect)]
        self._chan = [
            (c, name, float(self._zscale[c]))
            for c, name in enumerate(MEAS_CHANNELS)
            if self._use[c]
        ]
        self.ukf = BatchUKF(self.nx, alpha=c.alpha, beta=c.beta, kappa=c.kappa)
        w = self.ukf.w
        self._sigma = Sigma(w.Wm, w.Wc, float(w.c))
        self._ws = workspace(self.nx, N_CHANNELS)
        self._pool: ThreadPoolExecutor | None = None  # the second stepping thread, on demand
        self._ws_pool: tuple | None = None
        self.ids: dict[str, int] = {}
        self._rows: list | None = None
        self._vec_cache: dict[str, tuple] = {}
        self.usage = BankUsage(self.baseline)  # the usage rates (service.monitor.usage)
        self._alloc(capacity)

    _ROW_VECTORS = ("scale", "_zscale", "_q", "R", "_prm", "_cst")

    def _vectors(self, baseline: Baseline) -> tuple:
        """(baseline, its reduced parameters, and the rows of ``_ROW_VECTORS``): computed by
        the constructor of a bank on that baseline, so a row equals a bank's own vectors."""
        check_baseline_model(baseline, self.config.model)
        sig = baseline.model_dump_json()
        v = self._vec_cache.get(sig)
        if v is None:
            mv = model_vectors(self.config, baseline)
            v = (baseline, mv.rp, mv.scale, mv.zscale, mv.q, mv.R, mv.prm, mv.cst)
            self._vec_cache[sig] = v
        return v

    # -- storage -------------------------------------------------------------------------
    def _alloc(self, cap: int) -> None:
        n = self.nx
        self.x = np.zeros((cap, n))  # scaled filter state
        self.P = np.zeros((cap, n, n))
        self.ol = np.zeros((cap, n))  # SI open-loop (parallel) model state
        self.t_last = np.full(cap, -np.inf)
        self.carry = np.zeros((cap, N_CARRY))  # last current [A], C_Lk CUSUMs, detections, gate P12
        self.nis_avg = np.zeros(cap)
        self.t_init = np.zeros(cap)
        self.alarm = np.zeros((cap, len(ALARM_KINDS)), bool)
        # per alarm since when a change is due, then the leak mask's supply tracker
        self.pending = np.full((cap, N_PENDING), np.nan)
        self.counters: list[dict[str, int]] = [dict.fromkeys(COUNTERS, 0) for _ in range(cap)]
        self.events_log: list[list[AlarmEvent]] = [[] for _ in range(cap)]
        # per-actuator baseline rows (the default's until set_baseline)
        self.r_scale = np.tile(self.scale, (cap, 1))
        self.r_zscale = np.tile(self._zscale, (cap, 1))
        self.r_q = np.tile(self._q, (cap, 1))
        self.r_R = np.tile(self.R, (cap, 1, 1))
        self.r_prm = np.tile(self._prm, (cap, 1))
        self.r_cst = np.tile(self._cst, (cap, 1))
        self.r_base: list[tuple[Baseline, er.ReducedParams]] = [(self.baseline, self.rp)] * cap
        self.usage.resize(cap)
        self._views()

    def _views(self) -> None:
        """The kernels' named groups of the bank's arrays (rebuilt when they grow)."""
        self.bs = BankState(self.x, self.P, self.ol, self.t_last, self.carry, self.nis_avg,
                            self.t_init, self.alarm, self.pending)  # fmt: skip
        self.mr = ModelRows(self.r_q, self.r_R, self.r_scale, self.r_zscale, self.r_prm,
                            self.r_cst)  # fmt: skip

    _ARRAYS = ("x", "P", "ol", "t_last", "carry", "nis_avg", "t_init", "alarm", "pending",
               "r_scale", "r_zscale", "r_q", "r_R", "r_prm", "r_cst")  # fmt: skip

    def _grow(self) -> None:
        n_old = len(self.x)
        old = {a: getattr(self, a) for a in self._ARRAYS}
        counters = self.counters
        events = self.events_log
        bases = self.r_base
        self._alloc(2 * n_old)
        for a, v in old.items():
            getattr(self, a)[:n_old] = v
        self.counters[:n_old] = counters
        self.events_log[:n_old] = events
        self.r_base[:n_old] = bases
        self._views()

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

    def c_lk_changes_of(self, key: str) -> int:
        """Changes of C_Lk the change detector of actuator ``key`` has read (``MonitorConfig.
        c_lk_cusum_h``; docs/estimation.md, "C_Lk change detector (WH)")."""
        return int(self.carry[self.ids[key], CARRY_N])

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
                est=dict(zip(EST_KEYS, est_l[r], strict=False)),
                res=dict(zip(RES_KEYS, res_l[r], strict=False)),
                health=dict(zip(HEALTH_KEYS, h_l[r], strict=False)),
                events=rows.events[r],
            )
        return out

    def update_rows(self, samples: Sequence[tuple[str, Mapping]]) -> BankRows:
        """As ``update_many`` (same numbers) but the outputs stay numpy rows (``BankRows``):
        no per-sample dicts, for a fleet that logs or publishes arrays. The whole block is
        parsed with numpy and run through two compiled loops (``block_steps``, which returns
        to Python only for a (re-)initialisation, then ``block_rows``). A batch of one or two samples takes the
        per-round path (same numbers, less fixed cost per call)."""
        if len(samples) <= 2:
            return self.update_rows_rounds(samples)
        return self._run_block(samples)

    def index_of(self, key: str, baseline: Baseline | None = None) -> int:
        """Row of actuator ``key`` in the bank (created on first use); for ``update_arrays``.
        ``baseline``: the actuator's own, set when the row is created (see ``set_baseline``)."""
        new = key not in self.ids
        k = self._index(key)
        if new and baseline is not None:
            self.set_baseline(key, baseline)
        return k

    def baseline_of(self, key: str) -> Baseline:
        """The baseline actuator ``key`` runs on."""
        return self.r_base[self.ids[key]][0]

    def set_baseline(self, key: str, baseline: Baseline) -> None:
        """Run actuator ``key`` on ``baseline``: its filter starts again from its next sample
        (alarms cleared; counters kept)."""
        k = self._index(key)
        base, rp, *rows = self._vectors(baseline)
        for a, v in zip(self._ROW_VECTORS, rows, strict=True):
            getattr(self, "r_" + a.lstrip("_"))[k] = v
        self.r_base[k] = (base, rp)
        self.usage.set_baseline(k, base)
        self.t_last[k] = -np.inf
        self.alarm[k] = False
        self.pending[k] = np.nan
        self.nis_avg[k] = 0.0
        self.carry[k, POOL_CARRY] = 0.0  # the pooled C_Lk was learnt on the former baseline

    def update_arrays(self, ks: NDArray, t: NDArray, channels: NDArray) -> BankRows:
        """``update_rows`` for samples already in arrays (no dicts): actuator rows ``ks`` (n,)
        from ``index_of``, sample times ``t`` (n,) [s] and ``channels`` (n, 7) in the wire
        order of ``service.wire.messages.CHANNELS`` (x_cmd, i, x_s, x_j, p1, p2, p_sr; SI), NaN
        where a channel is absent. Same numbers as ``update_rows`` on the equivalent dicts
        (with None for the NaNs); ``BankRows.index`` refers to positions in these arrays."""
        sb = self.step_arrays(ks, t, channels)
        return empty_rows() if sb is None else self.rows_of(sb)

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
        vals = np.empty((n, len(INPUT_COLUMNS)))
        vals[:, IN_T] = t
        vals[:, IN_Z : IN_Z + N_CHANNELS] = ch[:, _WIRE_Z : _WIRE_Z + N_CHANNELS]
        vals[:, IN_I] = ch[:, _WIRE_I]
        vals[:, IN_X_CMD] = ch[:, _WIRE_X_CMD]
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
            return empty_rows()
        idx = np.concatenate([np.asarray(p[0], int) for p in parts])
        order = np.argsort(idx, kind="stable")
        evs = [e for p in parts for e in p[5]]
        # t, est, res, health and usage (None where the bank makes no usage rates)
        cat = [None if parts[0][c] is None else np.concatenate([p[c] for p in parts])[order]
               for c in (1, 2, 3, 4, 6, 7)]  # fmt: skip
        return BankRows(idx[order], *cat[:4], RowEvents.of([evs[j] for j in order]), *cat[4:])

    # -- block path ----------------------------------------------------------------------
    def _parse_block(self, samples: Sequence[tuple[str, Mapping]]):
        """Vectorised ``_parse`` of every sample: (ks, t, z (scaled), mask, cand, i_m, x_c)
        with NaN for an absent or bad i / x_cmd; counts bad_channel and skipped_nan (the
        time checks are sequential and done in ``block_steps``)."""
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
                obj = np.empty((n, len(INPUT_COLUMNS)), object)
                obj[:] = vl
                present = obj != None  # noqa: E711 (element-wise)
                vals = obj.astype(float)
                fast = True
            except (TypeError, ValueError, OverflowError):
                fast = False
        if not fast:  # anything else goes through _f, value by value, as _parse does
            present = np.zeros((n, len(INPUT_COLUMNS)), bool)
            vals = np.full((n, len(INPUT_COLUMNS)), math.nan)
            for j, row in enumerate(vl):
                for c, v in enumerate(row):
                    if v is not None:
                        present[j, c] = True
                        fv = _f(v)
                        if fv is not None:
                            vals[j, c] = fv
        return self._inputs(ks, vals, present)

    def _inputs(self, ks: NDArray, vals: NDArray, present: NDArray):
        """Filter inputs of a block from ``vals`` (n, 8) in the order of ``INPUT_COLUMNS``
        (t, x_s, x_j, p1, p2, p_sr, i, x_cmd) and ``present`` (n, 8): a present non-finite
        value counts as bad_channel, a sample with no usable value as skipped_nan
        (``prepare_inputs``)."""
        cnt = np.zeros((len(self.x), len(PREP_COUNTERS)), np.int64)
        t, z, mask, cand, i_m, x_c = prepare_inputs(
            ks, np.ascontiguousarray(vals), np.ascontiguousarray(present), self._use,
            self.r_zscale, cnt,
        )  # fmt: skip
        for k in np.flatnonzero(cnt.any(1)).tolist():
            c = self.counters[k]
            for col, name in enumerate(PREP_COUNTERS):
                c[name] += int(cnt[k, col])
        return ks, t, z, mask, cand, i_m, x_c

    def _run_block(self, samples: Sequence[tuple[str, Mapping]]) -> BankRows:
        if len(samples) == 0:
            return empty_rows()
        return self._run_inputs(*self._parse_block(samples))

    def _run_inputs(self, ks, t, z, mask, cand, i_m, x_c) -> BankRows:
        return self._rows_of(self._steps(ks, t, z, mask, cand, i_m, x_c))

    def _steps(self, ks, t, z, mask, cand, i_m, x_c) -> StepBlock:
        n = len(ks)
        nx = self.nx
        cnt = np.zeros((len(self.x), len(STEP_COUNTERS)), np.int64)
        sm = Samples(ks, t, z, mask, cand, i_m, x_c)
        so = _stepped(n, nx, cnt)
        extra: dict[int, list[AlarmEvent]] = {}
        parts = self._parts(ks)
        if parts is None:
            self._step_part(sm, so, self._ws, extra)
        else:  # the actuators split between this thread and the pool's (disjoint state)
            subs = [(Samples(*(a[idx] for a in sm)), _stepped(len(idx), nx, cnt)) for idx in parts]
            ex: list[dict[int, list[AlarmEvent]]] = [{}, {}]
            fut = self._pool.submit(self._step_part, *subs[1], self._ws_pool, ex[1])
            self._step_part(*subs[0], self._ws, ex[0])
            fut.result()
            for idx, (_, sub), e in zip(parts, subs, ex, strict=True):
                for full, part in zip(so[:-1], sub[:-1], strict=True):
                    full[idx] = part
                for j, evs in e.items():
                    extra[int(idx[j])] = evs
        for k in np.flatnonzero(cnt.any(1)).tolist():
            c = self.counters[k]
            for col, name in enumerate(STEP_COUNTERS):
                c[name] += int(cnt[k, col])
        snap = (so.SX, so.SPD, so.SOL, so.STI, so.SNA)
        return StepBlock(ks, t, z, mask, so.y, so.nis, so.acc, snap, extra, sm, so)

    def _parts(self, ks: NDArray) -> list[NDArray] | None:
        """Sample indices of the two halves of the actuators (k even, odd) when the block is
        worth two threads (``MonitorConfig.threads``), else None."""
        if self.config.threads < 2 or len(ks) < _MIN_SPLIT:
            return None
        odd = (ks & 1).astype(bool)
        n_odd = int(odd.sum())
        if n_odd == 0 or n_odd == len(ks):
            return None
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="monitor-step")
            self._ws_pool = workspace(self.nx, N_CHANNELS)
        return [np.flatnonzero(~odd), np.flatnonzero(odd)]

    def _step_part(self, sm: Samples, so: Stepped, ws: tuple, extra: dict) -> None:
        """``block_steps`` over the block ``sm`` (its own actuators), re-initialising where it
        stops; outputs into ``so``, re-initialisation events into ``extra``."""
        ks, t, z, mask, _, i_m, x_c = sm
        j, emit = 0, False
        while True:
            j, code = block_steps(j, emit, sm, self.bs, self.mr, self._sigma,
                                  self.config.max_gap_s, self._expect, ws, so)  # fmt: skip
            if code == STEP_OK:
                break
            k = int(ks[j])
            i_j = None if math.isnan(i_m[j]) else float(i_m[j])
            x_j = None if math.isnan(x_c[j]) else float(x_c[j])
            tj = float(t[j])
            if code == STEP_INIT:  # first sample or gap: (re-)initialise from this sample
                if math.isfinite(self.t_last[k]):
                    self.counters[k]["gap"] += 1
                self._init_state(k, z[j], mask[j], i_j, x_j)
                self.t_last[k] = tj
                self.t_init[k] = tj
                self.carry[k, CARRY_I] = i_j if i_j is not None else 0.0
                self.counters[k]["accepted"] += 1
            else:  # broken or diverged (the step was done and counted)
                keep = self.x[k].copy()
                self._init_state(k, z[j], mask[j], i_j, x_j)
                if code == STEP_DIVERGED:  # keep the parameter estimates, restart P
                    self.x[k, _PARAMS] = keep[_PARAMS]
                so.y[j] = 0.0
                so.nis[j] = 0.0
                self.counters[k]["reinit"] += 1
                self.t_init[k] = tj
                value = float(so.nis_avg[j]) if math.isfinite(so.nis_avg[j]) else 0.0
                extra[j] = [AlarmEvent(tj, "reinit", "raised", value)]
                log_reinit(self._key_of(k), tj, code != STEP_BROKEN, value)
            emit = True

    def _rows_of(self, sb: StepBlock) -> BankRows:
        ks, t = sb.ks, sb.t
        n = len(ks)
        est = np.zeros((n, len(EST_KEYS)))
        res = np.zeros((n, len(RES_KEYS)))
        health = np.zeros((n, len(HEALTH_KEYS)))
        fire = np.zeros((n, len(ALARM_KINDS)), np.int64)
        pool = np.zeros((n, 2))
        block_rows(sb.sm, sb.so, self.mr, self.alarm, self.pending,
                   Rows(est, res, health, fire, pool))  # fmt: skip
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
                        state = "raised" if fire[j, a] == FIRE_RAISED else "cleared"
                        ev.append(AlarmEvent(float(t[j]), ALARM_KINDS[a], state,
                                             float(health[j, HEALTH_INDICATOR[a]])))  # fmt: skip
                self.events_log[int(ks[j])].extend(ev)
        usage = self.usage.rates(ks, sb.acc, True, sb.so.SX, self.mr, sb.sm.z, sb.sm.mask, sel)
        return BankRows(sel, t[sel], est[sel], res[sel], health[sel], RowEvents(len(sel), at),
                        usage, pool[sel])  # fmt: skip

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
        z = [0.0] * N_CHANNELS
        mask = [False] * N_CHANNELS
        bad = 0
        zsk = self.r_zscale[k]
        for c, name, _ in self._chan:
            zs = zsk[c]
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
        b, rp = self.r_base[k]
        sc = self.r_zscale[k]
        x_s = z[Z_X_S] * sc[Z_X_S] if mask[Z_X_S] else (b.k_sv * i if i is not None else 0.0)
        x_j = z[Z_X_J] * sc[Z_X_J] if mask[Z_X_J] else (x_cmd if x_cmd is not None else 0.0)
        p_sr = b.p_sr_rated
        both_p = mask[Z_P1] and mask[Z_P2]
        if mask[Z_P_SR]:
            p_sr = z[Z_P_SR] * sc[Z_P_SR]
        elif both_p:
            p_sr = (z[Z_P1] + z[Z_P2]) * sc[Z_P1] - 2 * b.p_r
        p_sr = float(np.clip(p_sr, rp.p_vap, b.p_sr_rated))
        f_r = 0.0
        if both_p:
            f_r = (z[Z_P1] - z[Z_P2]) * sc[Z_P1] * b.area
        wh0 = {}
        if self.wh:  # chamber states: the measured pressures, else the symmetric split
            p12 = f_r / b.area
            wh0 = {
                "pt1": z[Z_P1] * sc[Z_P1] if mask[Z_P1] else b.p_r + 0.5 * (p_sr + p12),
                "pt2": z[Z_P2] * sc[Z_P2] if mask[Z_P2] else b.p_r + 0.5 * (p_sr - p12),
            }
        xs = by_name(self._names, x_s=x_s, v_s=0.0, x_j=x_j, v_j=0.0, f_r=f_r, p_sr=p_sr,
                      c_lk=b.c_lk, i_b=0.0, **wh0)  # fmt: skip
        self.x[k] = xs / self.r_scale[k]
        self.P[k] = np.diag((self._p0 / self.r_scale[k]) ** 2)
        self.ol[k] = xs
        self.ol[k, S_P_SR], self.ol[k, S_C_LK] = b.p_sr_rated, b.c_lk
        self.nis_avg[k] = 0.0
        self.carry[k, CARRY_GP] = self.carry[k, CARRY_GM] = 0.0  # the change detector restarts
        self.carry[k, CARRY_P12] = f_r / b.area  # the C_Lk gate's low-passed P1 - P2 [Pa]
        self.carry[k, CARRY_T_FAST] = -np.inf  # no fast motion yet

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
                self.carry[k, CARRY_I] = p[3] if p[3] is not None else 0.0
                self.counters[k]["accepted"] += 1
                self._outputs(
                    np.array([k]), np.array([t]), z1, m1, np.zeros((1, N_CHANNELS)), np.zeros(1), [[]],
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
        y = np.zeros((B, N_CHANNELS))
        nis = np.zeros(B)
        nis_avg = np.zeros(B)
        flag = np.zeros(B, np.int64)
        sm = Samples(ks.astype(np.int64), t, z, mask, np.ones(B, np.bool_), i_m, x_c)
        bank_step(sm, self.bs, self.mr, self._sigma, self._ws, y, nis, nis_avg, flag)
        bad, diverged = flag == STEP_BROKEN, flag == STEP_DIVERGED
        evs: list[list[AlarmEvent]] = [[] for _ in range(B)]
        for j in np.flatnonzero(bad | diverged):
            k = int(ks[j])
            keep = self.x[k].copy()
            self._init_state(k, z[j], mask[j], parsed[j][3], parsed[j][4])
            if not bad[j]:  # keep the parameter estimates, restart the covariance
                self.x[k, _PARAMS] = keep[_PARAMS]
            y[j] = 0.0
            nis[j] = 0.0
            self.counters[k]["reinit"] += 1
            self.t_init[k] = t[j]
            value = float(nis_avg[j]) if math.isfinite(nis_avg[j]) else 0.0
            evs[j].append(AlarmEvent(float(t[j]), "reinit", "raised", value))
            log_reinit(self._key_of(k), float(t[j]), not bad[j], value)
        for k in ks:
            self.counters[k]["accepted"] += 1
        self._outputs(ks, t, z, mask, y, nis, evs, slot_of, out)

    def _outputs(self, ks, t, z, mask, y, nis, evs, slots, out) -> None:
        n = len(ks)
        # zeros, not empty: every column is written by output_rows, but a row must never
        # expose uninitialised memory should a column ever be skipped
        est = np.zeros((n, len(EST_KEYS)))
        res = np.zeros((n, len(RES_KEYS)))
        health = np.zeros((n, len(HEALTH_KEYS)))
        fire = np.zeros((n, len(ALARM_KINDS)), np.int64)
        pool = np.zeros((n, 2))
        sm = Samples(np.asarray(ks, np.int64), t, z, mask, np.ones(n, np.bool_), t, t)
        pd = np.diagonal(self.P, axis1=1, axis2=2).copy()
        output_rows(self.bs, pd, self.mr, sm, y, nis, Rows(est, res, health, fire, pool))
        usage = self.usage.rates(sm.ks, sm.cand, False, self.x, self.mr, z, mask)
        for j, a in zip(*np.nonzero(fire), strict=True):
            state = "raised" if fire[j, a] == FIRE_RAISED else "cleared"
            evs[j].append(
                AlarmEvent(
                    float(t[j]), ALARM_KINDS[a], state, float(health[j, HEALTH_INDICATOR[a]])
                )
            )
        for j in np.flatnonzero([bool(e) for e in evs]):
            self.events_log[int(ks[j])].extend(evs[j])
        if self._rows is not None:  # update_rows: keep the arrays
            self._rows.append((slots, t, est, res, health, evs, usage, pool))
            return
        est_l, res_l, h_l, t_l = est.tolist(), res.tolist(), health.tolist(), t.tolist()
        for j, slot in enumerate(slots):
            out[slot] = MonitorOutput(
                t=t_l[j],
                est=dict(zip(EST_KEYS, est_l[j], strict=False)),
                res=dict(zip(RES_KEYS, res_l[j], strict=False)),
                health=dict(zip(HEALTH_KEYS, h_l[j], strict=False)),
                events=evs[j],
            )


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


EST_KEYS, RES_KEYS, HEALTH_KEYS = EST_KEYS, RES_KEYS, HEALTH_KEYS
