"""`pid-adaptive`: a classical adaptive gain scheduler (online estimation + certainty equivalence).

What it measures is what a mill's data acquisition records, sampled at 10 kHz: piston position,
velocity and acceleration, chamber and supply pressure, the servo-amplifier command and the
rolling force from the stand's load cells (``info["signals"]`` of the environments). What it knows
is the plant's data sheet, Table 1, for everything but the two parameters that drift: the damping c1 and the leakage Ct.

Estimation, once per decision period, by least squares with exponential forgetting (recursive
least squares in information form: the information matrix and vector decay by
``exp(-period / tau_s)`` and gain that period's samples):

* leakage, from the continuity equation (4) integrated over the period:
  ``int(QL - Ap v) dt - (Ap (L1 + x) / beta_e) dpL = Ct int(pL - pb) dt``, with the valve flow QL
  of the measured command from the valve's model (1)-(3), evaluated by `plant_rhs` itself. Where the
  valve has dynamics (``valve_wn_hz > 0``, the v1 loop), the flow follows the spool, not the command:
  the spool's position comes from an observer that runs `plant_rhs`'s own spool equations (affine in
  the spool state, so exactly discretised once, `spool_discretization`) along the measured command,
  which the recorded signals hold over each sample interval;
* damping, from the force balance (8): ``mt (a_model - a) - (FL(t) - FL) = c1 v``, where a_model
  is the plant's own right-hand side (`plant_rhs`, the one implementation) evaluated at the
  measured x, v, pL with c1 = 0 and the nominal load, FL(t) the load cells' rolling force, and
  the seal friction's bristle state comes from an observer that integrates the same right-hand
  side's bristle rate (trapezoidal rule) along the measured velocity. Both sides are high-passed
  at `highpass_hz` against slow model errors; c1 is the regression coefficient on the velocity.

Gains: the oracle's table (`GainTable`, tuned offline per plant) at the estimated (c1, Ct), the
certainty-equivalence principle; until the damping regression has gathered `min_info` (enough
motion above the high-pass), the table's gains at the prior estimate, the geometric centre of
the table's (c1, Ct) ranges. (Starting from the pid-robust gains instead and switching to the
table's mid-transient cost 4 % more on the startup task's tuning plants: 12.14 against 11.67.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from millvib_env._checks import as_float, shown
from millvib_env.control.base import GainTable, PerEnvGains
from millvib_env.envs.actions import GainMap
from millvib_env.envs.filter_design import butter_sos
from millvib_env.envs.period import pairwise_sum, sosfilt_into
from millvib_env.params import MillParams
from millvib_env.plant.model import (A_QL, C_UEXT, D_VW, IPL, IV, IVS, IX, IXS, IZ, NAUX, NC, NY, P_FS, P_S0, pack,
                                     plant_rhs)


def spool_discretization(p: np.ndarray, dt: float) -> np.ndarray:
    """(2, 4): the spool of the plant `p` (packed) over one sample interval dt with the command held, as
    ``s_k = Phi s_(k-1) + gamma u_k`` for s = (xs, vs): columns Phi, gamma and the steady state per volt
    (``s = steady u`` under a constant command). The spool equations are `plant_rhs`'s own, read off it (they
    are affine in the spool state and the command) and discretised exactly (the matrix exponential). A valve
    without dynamics (``valve_wn_hz = 0``, where plant_rhs's flow follows the command and ignores the spool):
    Phi = I and the rest zero, so the observer's spool stays at 0."""
    out = np.zeros((2, 4))
    out[0, 0] = out[1, 1] = 1.0
    if not p[D_VW] > 0.0:
        return out

    def rate(xs: float, vs: float, u: float) -> np.ndarray:
        y, dy, aux, c = np.zeros(NY), np.empty(NY), np.empty(NAUX), np.zeros(NC)
        y[IXS], y[IVS], c[C_UEXT] = xs, vs, u
        plant_rhs(0.0, y, p, c, dy, aux)
        return np.array([dy[IXS], dy[IVS]])

    free = rate(0.0, 0.0, 0.0)
    a = np.column_stack([rate(1.0, 0.0, 0.0) - free, rate(0.0, 1.0, 0.0) - free])
    b = rate(0.0, 0.0, 1.0) - free
    from scipy.linalg import expm, solve

    m = expm(np.block([[a, b[:, None]], [np.zeros((1, 3))]]) * dt)
    out[:, :3] = m[:2, :3]
    out[:, 3] = solve(a, -b)
    return out


@njit(cache=True)
def model_acceleration(t, x, v, pL, u, z0, p, out, flow, spool, s, start):
    """Acceleration of the plant model `p` (c1 = 0 there) at the measured samples, with the bristle
    state integrated along the measured velocity (trapezoidal rule on plant_rhs's bristle rate,
    which is affine in z; the trapezoidal rule adds no phase lag, which would read as damping),
    and the valve flow QL of the measured command (the valve's model, Eq. 1-3, from the same
    plant_rhs) through the spool observer `spool` (`spool_discretization`): s (xs, vs) is the spool at
    the first sample, advanced in place to the last; where `start` (an episode's first sample), the
    steady state of the first command. Writes out[k] and flow[k]; returns the bristle state after the
    last sample."""
    y = np.zeros(NY)
    dy = np.empty(NY)
    aux = np.empty(NAUX)
    c = np.zeros(NC)  # the PID off: the measured command is the valve's input
    z_ref = p[P_FS] / p[P_S0]
    z = z0
    d_prev = 0.0
    r_prev = 0.0
    if start and x.shape[0] > 0:
        s[0] = spool[0, 3] * u[0]
        s[1] = spool[1, 3] * u[0]
    for k in range(x.shape[0]):
        y[IX] = x[k]
        y[IV] = v[k]
        y[IPL] = pL[k]
        y[IZ] = 0.0
        c[C_UEXT] = 0.0
        plant_rhs(t[k], y, p, c, dy, aux)
        dz0 = dy[IZ]
        y[IZ] = z_ref
        plant_rhs(t[k], y, p, c, dy, aux)
        rate = (dz0 - dy[IZ]) / z_ref  # dz/dt = dz0 - rate * z (LuGre is affine in z)
        if k > 0:
            h = 0.5 * (t[k] - t[k - 1])
            z = (z * (1.0 - h * r_prev) + h * (d_prev + dz0)) / (1.0 + h * rate)
            xs = spool[0, 0] * s[0] + spool[0, 1] * s[1] + spool[0, 2] * u[k]
            s[1] = spool[1, 0] * s[0] + spool[1, 1] * s[1] + spool[1, 2] * u[k]
            s[0] = xs
        d_prev, r_prev = dz0, rate
        y[IZ] = z
        y[IXS] = s[0]
        y[IVS] = s[1]
        c[C_UEXT] = u[k]
        plant_rhs(t[k], y, p, c, dy, aux)
        out[k] = dy[IV]
        flow[k] = aux[A_QL]
    return z


@njit(cache=True)
def _estimate_period(t, x, v, pL, u, a, FL, last, z0, flow_prev, has_prev, acc, zi, sos, p_model, consts, decay,
                     dt, spool, s):
    """One environment's period of `PlantEstimator.update`, compiled: the same operations in the same order as
    the numpy and scipy calls it replaces (numpy's pairwise sums, scipy's sosfilt, the same dot products), so
    the same numbers. `last` (t, x, v, pL, u) and `flow_prev` (net flow, compliance, leak pressure, pL): the
    previous period's last samples, used where `has_prev` (every period but an episode's first), and
    overwritten. `acc`: the forgotten sums (ct_num, ct_den, R, r), updated; `zi`: the two high-passes' section
    states, updated; `s`: the spool observer's state at the previous period's last sample, advanced. Returns the
    bristle state after the last sample."""
    ap, l1, beta_e, pb = consts[0], consts[1], consts[2], consts[3]
    mt, fl0, v_scale = consts[4], consts[5], consts[6]
    m = x.shape[0]
    j = 1 if has_prev else 0
    n = m + j
    ct, cx, cv, cp, cu = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    if has_prev:
        ct[0], cx[0], cv[0], cp[0], cu[0] = last[0], last[1], last[2], last[3], last[4]
    ct[j:], cx[j:], cv[j:], cp[j:], cu[j:] = t, x, v, pL, u
    a_model, ql = np.empty(n), np.empty(n)
    z = model_acceleration(ct, cx, cv, cp, cu, z0, p_model, a_model, ql, spool, s, not has_prev)
    last[0], last[1], last[2], last[3], last[4] = ct[n - 1], cx[n - 1], cv[n - 1], cp[n - 1], cu[n - 1]
    # leakage: continuity integrated over the period (trapezoidal rule, from the previous sample on)
    net, comp, lk, pl = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    if has_prev:
        net[0], comp[0], lk[0], pl[0] = flow_prev[0], flow_prev[1], flow_prev[2], flow_prev[3]
    for i in range(m):
        net[j + i] = ql[j + i] - ap * v[i]
        comp[j + i] = ap * (l1 + x[i]) / beta_e
        lk[j + i] = pL[i] - pb
        pl[j + i] = pL[i]
    if n > 1:
        terms = np.empty(n - 1)
        for i in range(n - 1):
            terms[i] = 0.5 * (net[i + 1] + net[i]) * dt - 0.5 * (comp[i + 1] + comp[i]) * (pl[i + 1] - pl[i])
        lhs = pairwise_sum(terms, n - 1)
        for i in range(n - 1):
            terms[i] = 0.5 * (lk[i + 1] + lk[i]) * dt
        rhs = pairwise_sum(terms, n - 1)
        acc[0] = decay * acc[0] + lhs * rhs
        acc[1] = decay * acc[1] + rhs * rhs
    flow_prev[0], flow_prev[1], flow_prev[2], flow_prev[3] = net[n - 1], comp[n - 1], lk[n - 1], pl[n - 1]
    # damping: the force balance's residual against the model without damping, high-passed
    force = np.empty(m)
    scaled = np.empty(m)
    for i in range(m):
        force[i] = mt * (a_model[j + i] - a[i]) - (FL[i] - fl0)
        scaled[i] = v[i] / v_scale
    phi, rhs_f = np.empty(m), np.empty(m)
    sosfilt_into(sos, scaled, zi[0], phi)
    sosfilt_into(sos, force, zi[1], rhs_f)
    acc[2] = decay * acc[2] + np.dot(phi, phi)
    acc[3] = decay * acc[3] + np.dot(phi, rhs_f)
    return z


@dataclass(frozen=True)
class EstimatorSettings:
    """tau_s: forgetting time constant (s); highpass_hz: high-pass of the damping regression;
    min_info: excitation needed before the damping estimate is used, as the forgotten sum of
    (high-passed velocity / 1 mm/s)^2 over samples."""

    tau_s: float = 0.2
    highpass_hz: float = 10.0
    min_info: float = 50.0

    def __post_init__(self) -> None:
        for name in ("tau_s", "highpass_hz", "min_info"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(as_float(value)) \
                    or value <= 0:
                raise ValueError(f"EstimatorSettings.{name} = {shown(value)} is invalid: a finite number > 0")


class PlantEstimator:
    """Online estimates of c1 and Ct for a batch of environments (module docstring)."""

    C1_RANGE = (1.0e4, 1.0e8)
    CT_RANGE = (1.0e-17, 1.0e-7)
    V_SCALE = 1e-3  # m/s: regressor scaling

    def __init__(self, params: MillParams, settings: EstimatorSettings, sample_rate_hz: float = 10_000.0):
        self.params, self.settings, self.fs = params, settings, sample_rate_hz
        self.p_model = pack(params.replace(c1=0.0))  # valve flow gain Cd W sqrt(2/rho) Ksv Kp1 (data sheet)
        self.sos = butter_sos(2, settings.highpass_hz, "highpass", sample_rate_hz)
        self._consts = np.array([params.Ap, params.L1, params.beta_e, params.pb, params.mt, params.FL, self.V_SCALE])
        self.spool_model = spool_discretization(self.p_model, 1.0 / sample_rate_hz)
        self.n = 0
        self.reset_all(0)

    def reset_all(self, n: int) -> None:
        self.n = n
        self.z = np.zeros(n)
        self.acc = np.zeros((n, 4))  # the forgotten sums: ct_num, ct_den, R (damping information), r
        self.zi = np.zeros((n, 2, self.sos.shape[0], 2))
        self.c1_hat = np.full(n, np.nan)
        self.ct_hat = np.full(n, np.nan)
        self.flow_prev = np.zeros((n, 4))  # the previous period's last net flow, compliance, leak pressure, pL
        self.last = np.zeros((n, 5))  # the previous period's last t, x, v, pL, u
        self.has_prev = np.zeros(n, dtype=bool)  # whether flow_prev, last and spool hold a previous period
        self.spool = np.zeros((n, 2))  # the spool observer's (xs, vs) at the previous period's last sample
        self.err_c1: list[list[float]] = [[] for _ in range(n)]
        self.err_ct: list[list[float]] = [[] for _ in range(n)]

    def grow(self, n: int) -> None:
        if n <= self.n:
            return
        names = ("z", "acc", "zi", "c1_hat", "ct_hat", "flow_prev", "last", "has_prev", "spool", "err_c1", "err_ct")
        old, k = {name: getattr(self, name) for name in names}, self.n
        self.reset_all(n)
        for name in names:
            getattr(self, name)[:k] = old[name]

    def start(self, i: int) -> None:
        self.z[i] = 0.0
        self.acc[i] = 0.0
        self.zi[i] = 0.0
        self.c1_hat[i] = self.ct_hat[i] = np.nan
        self.has_prev[i] = False
        self.err_c1[i], self.err_ct[i] = [], []

    def update(self, i: int, sig: dict) -> None:
        m = sig["x"].size
        if m >= 2 and abs((sig["t"][1] - sig["t"][0]) * self.fs - 1.0) > 1e-6:
            raise ValueError(f"pid-adaptive's estimator runs at {self.fs:g} Hz but the signals are sampled at "
                             f"{1.0 / (sig['t'][1] - sig['t'][0]):g} Hz: build it with the env's sample_rate_hz")
        dt = 1.0 / self.fs
        decay = math.exp(-m * dt / self.settings.tau_s)
        self.z[i] = _estimate_period(sig["t"], sig["x"], sig["v"], sig["pL"], sig["u"], sig["a"], sig["FL"],
                                     self.last[i], self.z[i], self.flow_prev[i], self.has_prev[i],
                                     self.acc[i], self.zi[i], self.sos, self.p_model, self._consts, decay, dt,
                                     self.spool_model, self.spool[i])
        self.has_prev[i] = True
        ct_num, ct_den, info, r = self.acc[i]
        if ct_den > 0:
            self.ct_hat[i] = float(np.clip(ct_num / ct_den, *self.CT_RANGE))
        if info >= self.settings.min_info:
            self.c1_hat[i] = float(np.clip(r / info / self.V_SCALE, *self.C1_RANGE))

    def record_error(self, i: int, c1: float, ct: float) -> None:
        if math.isfinite(self.c1_hat[i]):
            self.err_c1[i].append(abs(math.log10(self.c1_hat[i] / c1)))
        if math.isfinite(self.ct_hat[i]):
            self.err_ct[i].append(abs(math.log10(self.ct_hat[i] / ct)))


class AdaptivePolicy(PerEnvGains):
    """`pid-adaptive`: the oracle's gains at the online estimate of (c1, Ct)."""

    name = "pid-adaptive"
    needs_signals = True

    def __init__(self, table: GainTable, gain_map: GainMap, settings: EstimatorSettings, params: MillParams,
                 sample_rate_hz: float = 10_000.0):
        self.table, self.gain_map = table, gain_map
        self.prior = (float(np.sqrt(table.c1_grid[0] * table.c1_grid[-1])),
                      float(np.sqrt(table.ct_grid[0] * table.ct_grid[-1])))
        self.fallback = table(*self.prior)
        self.estimator = PlantEstimator(params, settings, sample_rate_hz)
        self.nominal = params
        self._actions = None

    def gains_for(self, c1: float, ct: float) -> np.ndarray:
        if not math.isfinite(c1):
            return self.fallback
        return self.table(c1, ct if math.isfinite(ct) else self.nominal.Ct)

    def on_reset(self, infos, indices) -> None:
        self._ensure(max(indices) + 1)
        self.estimator.grow(self._held.shape[0])
        for i in indices:
            self.estimator.start(i)
            self._set(i, {"c1": np.nan, "Ct": np.nan})

    def on_step(self, infos) -> None:
        self._ensure(len(infos))
        self.estimator.grow(len(infos))
        for i, info in enumerate(infos):
            if "signals" not in info:
                raise ValueError("pid-adaptive needs the measured signals: set the env core's record_signals "
                                 "(the benchmark's evaluation loop does)")
            self.estimator.update(i, info["signals"])
            self.estimator.record_error(i, info["params"]["c1"], info["params"]["Ct"])
        n = len(infos)
        c1, ct = self.estimator.c1_hat[:n], self.estimator.ct_hat[:n]
        self._held[:n] = self.gain_map.action(self.gains_at(c1, ct))  # every environment's in one call
        for i in range(n):
            self._plant[i] = (c1[i], ct[i])

    def gains_at(self, c1: np.ndarray, ct: np.ndarray) -> np.ndarray:
        """(n, 3): `gains_for` of each estimate (c1[k], Ct[k]), the table read once for all."""
        out = np.empty((len(c1), 3))
        known = np.isfinite(c1)
        out[~known] = self.fallback
        if known.any():
            ct_known = ct[known]
            out[known] = self.table.at(c1[known], np.where(np.isfinite(ct_known), ct_known, self.nominal.Ct))
        return out

    def _set(self, i: int, params: dict) -> None:
        self._plant[i] = (params["c1"], params["Ct"])
        self._held[i] = self.gain_map.action(self.gains_for(params["c1"], params["Ct"]))

    def episode_extras(self, i: int) -> dict:
        e1, et = self.estimator.err_c1[i], self.estimator.err_ct[i]
        return {"c1_log_error": float(np.mean(e1)) if e1 else math.nan,
                "ct_log_error": float(np.mean(et)) if et else math.nan}
