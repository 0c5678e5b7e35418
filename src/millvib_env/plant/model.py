"""The plant's equations, once: the right-hand side every integrator calls.

The state and auxiliary-output layouts are declared once, below (`STATES`, `AUX`): names, units,
meanings and typical magnitudes; every index constant, `state_scale`, the `SimResult` fields, the
linearisation and the environments read them from there.

State vector ``y`` (``NY = 7``), SI units:

=======  ======  =============================================================================
index    name    meaning
=======  ======  =============================================================================
0        x       piston displacement (m), positive = extending (pressing)
1        v       piston velocity (m/s)
2        pL      rod-less chamber pressure (Pa)
3        z       LuGre mean bristle deflection (m)
4        uI      the analog PID's integral term (V): d(uI)/dt = KI * e (the paper's loop only)
5        xs      servo-valve spool position (m) (a valve with dynamics only; 0 for the ideal valve)
6        vs      servo-valve spool velocity (m/s) (likewise)
=======  ======  =============================================================================

Drive vector ``c`` (``NC``), held constant over an integration segment:
KP, KI, KD (PID gains), xd (set-point, m), u_ext (external valve command, V, added to the PID
output), pid_on (1.0 or 0.0), dFL (rolling-force offset, N), eccentricity force amplitude (N),
angular frequency (rad/s) and phase (rad), KPL (pressure-feedback gain, V/Pa) and its reference
pressure pL_ref (Pa), a within-run change of the plant: start time t0 (s), duration (s) and
the natural logs of the final factors on c1 and Ct, and KFF (force feedforward gain, V/N).

The analog PID inside the right-hand side (pid_on = 1) is the paper's continuous loop, kept for its
reproduction and the v0 environments. A sampled (digital) controller is not part of the plant: it
runs outside (`millvib_env.loop`), sets pid_on = 0 and holds its command in u_ext.

A plant change is part of the drive, not a second copy of the equations: c1(t) = c1 F_c1^s(t) and
Ct(t) = Ct F_Ct^s(t), with s(t) the smoothstep 3 tau^2 - 2 tau^3 of tau = (t - t0) / duration
clipped to [0, 1] (`change_fraction`). The change is continuous with a continuous rate, so the
adaptive integrators follow it without a restart, and the geometric interpolation spreads a
1000-fold leakage rise evenly over its duration on a log scale.

Equations (paper numbering):

* (11) PID:  u = pid_on * (KP e + uI - KD v - KPL (pL - pL_ref) + KFF dF) + u_ext,  e = xd - x,
  saturated at +-u_max. The pressure-feedback term (not in the paper; KPL = 0 by default, and then
  the term is skipped, so trajectories are bit for bit those without it) is the textbook active
  damping of a hydraulic servo: a load-pressure rise closes the valve, as leakage would. The
  feedforward term (not in the paper either; KFF = 0 by default, skipped likewise) reads the load
  cells: dF = FL(t) - FL is the rolling force's deviation from its nominal value (force steps and
  roll eccentricity), and KFF dF opens the valve against a force rise before the position moves;
  KFF = KPL / Ap cancels the pressure feedback's static give under a load change.
  The derivative acts on the measurement (-KD v), so a set-point step gives no derivative kick.
  Storing the integral *term* uI (not int e) makes gain changes bumpless in the integral term.
  Integration stops while the output saturates in the direction of e (anti-windup).
* (2)-(3) servo amplifier and valve. The paper's ideal valve (valve_wn_hz = 0): xv = Ksv Kp1 u.
  A valve with dynamics (valve_wn_hz > 0, not in the paper): the spool follows the command through
  a second-order lag, xs'' = wn^2 (Ksv Kp1 u - xs) - 2 zeta wn xs', the standard datasheet model of
  a servo valve (its phase is -90 deg at wn). Either way the port opening is limited by the spool
  stroke, xv = clip(xs, -xv_max, xv_max).
* (1) orifice flow, with supply pressure ps(t) = ps (1 + A (sin wt + h2 sin 2wt + h3 sin 3wt)):
  QL = Cd W xv sqrt(2/rho) R(ps(t) - pL) if xv >= 0, QL = Cd W xv sqrt(2/rho) R(pL - pt) otherwise,
  where R(dp) = dp / (dp^2 + dp_reg^2)^(1/4) is a regularised signed root: the flow reverses with
  the pressure drop instead of taking the root of a negative number.
* (4) continuity:  dpL/dt = beta_e / (Ap (L1 + x)) * (QL - Ap v - Ct (pL - pb)).
* (5)-(7) LuGre:  g(v) = fc + (fs - fc) exp(-(v/vs)^2),  dz/dt = v - sigma0 |v| z / g(v),
  Ff = sigma0 z + sigma1 dz/dt + sigma2 v.
* (8) force balance:  mt dv/dt = Ap pL - Ab pb - c1 v - k1 x - Ff - FL(t),
  FL(t) = FL + dFL + F_ecc sin(w_ecc t + phi_ecc).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from millvib_env._checks import as_float, shown
from millvib_env.params import PARAM_FIELDS, MillParams, PIDGains

# --- layout of the vectors the compiled code reads: declared once ------------------------------
@dataclass(frozen=True)
class Signal:
    """One entry of a vector layout: its name, unit and meaning."""

    name: str
    unit: str
    meaning: str


#: the state vector y, in order (the module docstring's table)
STATES = (
    Signal("x", "m", "piston displacement, positive = extending (pressing)"),
    Signal("v", "m/s", "piston velocity"),
    Signal("pL", "Pa", "rod-less chamber pressure"),
    Signal("z", "m", "LuGre mean bristle deflection"),
    Signal("uI", "V", "the analog PID's integral term (the paper's continuous loop only)"),
    Signal("xs", "m", "servo-valve spool position (a valve with dynamics; 0 for the ideal valve)"),
    Signal("vs", "m/s", "servo-valve spool velocity (a valve with dynamics; 0 for the ideal valve)"),
)
#: the auxiliary outputs every right-hand-side evaluation writes, in order
AUX = (
    Signal("a", "m/s^2", "piston acceleration"),
    Signal("u", "V", "servo-amplifier command after its saturation"),
    Signal("xv", "m", "valve port opening (the spool, limited to its stroke)"),
    Signal("QL", "m^3/s", "valve flow into the chamber"),
    Signal("Ff", "N", "seal friction"),
    Signal("ps", "Pa", "supply pressure with the pump's pulsation"),
)
STATE_NAMES = tuple(s.name for s in STATES)
AUX_NAMES = tuple(s.name for s in AUX)
NY = len(STATES)
IX, IV, IPL, IZ, IUI, IXS, IVS = (STATE_NAMES.index(n) for n in ("x", "v", "pL", "z", "uI", "xs", "vs"))
#: the states of the valve's dynamics: constant (zero) for the ideal valve, and then left out of the
#: integrator's error norm and of the linearisation
VALVE_STATES = (IXS, IVS)
#: the states before the valve's (the valve's come last, so the ideal valve's norm is a prefix)
N_CORE_STATES = NY - len(VALVE_STATES)
assert VALVE_STATES == tuple(range(N_CORE_STATES, NY))
NAUX = len(AUX)
A_ACC, A_U, A_XV, A_QL, A_FF, A_PS = (AUX_NAMES.index(n) for n in ("a", "u", "xv", "QL", "Ff", "ps"))


def state_scale(params: MillParams) -> np.ndarray:
    """Typical magnitude of each state (`STATES` order); the integrators' absolute tolerance is
    rtol * scale."""
    typical = {"x": 1e-3, "v": 1.0, "pL": params.ps, "z": params.fs / params.sigma0, "uI": 10.0,
               "xs": 1e-3, "vs": 1.0}
    return np.array([typical[n] for n in STATE_NAMES])


_P = {name: i for i, name in enumerate(PARAM_FIELDS)}
NP = len(PARAM_FIELDS)
P_AP, P_AB, P_MT, P_C1, P_K1, P_FL, P_CT = (_P[k] for k in ("Ap", "Ab", "mt", "c1", "k1", "FL", "Ct"))
P_PS, P_PT, P_PB, P_BETA, P_RHO, P_CD, P_W = (_P[k] for k in ("ps", "pt", "pb", "beta_e", "rho", "Cd", "W"))
P_KP1, P_KSV, P_L1, P_L = (_P[k] for k in ("Kp1", "Ksv", "L1", "L"))
P_S0, P_S1, P_S2, P_FC, P_FS, P_VS = (_P[k] for k in ("sigma0", "sigma1", "sigma2", "fc", "fs", "vs"))
P_PA, P_PF, P_PH2, P_PH3, P_DPR, P_UMAX = (
    _P[k] for k in ("pulse_amp", "pulse_freq", "pulse_h2", "pulse_h3", "dp_reg", "u_max"))
P_VWN, P_VZETA, P_XVMAX = (_P[k] for k in ("valve_wn_hz", "valve_zeta", "xv_max"))

NC = 17
(C_KP, C_KI, C_KD, C_XD, C_UEXT, C_PID, C_DFL, C_EA, C_EW, C_EP, C_KPL, C_PLREF,
 C_CHG_T0, C_CHG_DT, C_CHG_LC1, C_CHG_LCT, C_KFF) = range(NC)

# derived coefficients, appended to the parameter vector by `pack` (computed once per plant)
ND = 12
D_KQ, D_DPR2, D_BA, D_W, D_INVVS, D_FSC, D_ABPB, D_INVM, D_KXV, D_KQX, D_VW, D_ULIM = range(NP, NP + ND)
NPACK = NP + ND


def pack(params: MillParams) -> np.ndarray:
    """The vector `plant_rhs` reads: MillParams fields (order `PARAM_FIELDS`) + derived constants."""
    p = np.empty(NPACK)
    p[:NP] = params.to_array()
    p[D_KQ] = params.Cd * params.W * math.sqrt(2.0 / params.rho) * params.Ksv * params.Kp1
    p[D_DPR2] = params.dp_reg * params.dp_reg
    p[D_BA] = params.beta_e / params.Ap
    p[D_W] = 2.0 * math.pi * params.pulse_freq
    p[D_INVVS] = 1.0 / params.vs
    p[D_FSC] = params.fs - params.fc
    p[D_ABPB] = params.Ab * params.pb
    p[D_INVM] = 1.0 / params.mt
    p[D_KXV] = params.Ksv * params.Kp1
    p[D_KQX] = params.Cd * params.W * math.sqrt(2.0 / params.rho)  # flow per (m of opening, sqrt Pa)
    p[D_VW] = 2.0 * math.pi * params.valve_wn_hz
    p[D_ULIM] = params.xv_max / p[D_KXV]  # the command that opens the ideal valve to its stroke (inf: none)
    bad = [what for k, what in _DERIVED.items() if not math.isfinite(p[k])]
    if bad:
        raise ValueError(f"MillParams give a model coefficient beyond a float: {', '.join(bad)} (a value too large "
                         "or too small for the plant's equations)")
    return p


#: the derived coefficients that must be finite, as the error names them
_DERIVED = {D_KQ: "Cd W sqrt(2/rho) Ksv Kp1", D_DPR2: "dp_reg^2", D_BA: "beta_e/Ap", D_W: "2 pi pulse_freq",
            D_INVVS: "1/vs", D_FSC: "fs - fc", D_ABPB: "Ab pb", D_INVM: "1/mt", D_KXV: "Ksv Kp1",
            D_KQX: "Cd W sqrt(2/rho)", D_VW: "2 pi valve_wn_hz"}


@njit(cache=True, inline="always")
def supply_pressure(t, p):
    """ps(t) with pump pulsation (Pa)."""
    w = p[D_W] * t
    ripple = math.sin(w)
    if p[P_PH2] != 0.0:
        ripple += p[P_PH2] * math.sin(2.0 * w)
    if p[P_PH3] != 0.0:
        ripple += p[P_PH3] * math.sin(3.0 * w)
    return p[P_PS] * (1.0 + p[P_PA] * ripple)


@njit(cache=True)
def supply_ripple_rows(times, packs):
    """ps(t) - ps (Pa), `supply_pressure`'s pulsation, of many plants in one compiled call (a model's horizon per
    environment, `control.mpc`): row r of `times` (s) on the plant packed in row r of `packs`, zero for a plant
    without pulsation (its amplitude P_PA zero)."""
    out = np.zeros(times.shape)
    for r in range(times.shape[0]):
        p = packs[r]
        if p[P_PA] != 0.0:
            for j in range(times.shape[1]):
                out[r, j] = supply_pressure(times[r, j], p) - p[P_PS]
    return out


@njit(cache=True)
def change_fraction(t, t0, duration):
    """Progress s in [0, 1] of a within-run plant change at time t: smoothstep of (t - t0)/duration."""
    if t <= t0:
        return 0.0
    if t >= t0 + duration:
        return 1.0
    tau = (t - t0) / duration
    return tau * tau * (3.0 - 2.0 * tau)


@njit(cache=True, inline="always")
def damping_and_leakage(t, p, c):
    """c1(t) and Ct(t): the plant's values, moved by a within-run change when the drive has one."""
    c1 = p[P_C1]
    ct = p[P_CT]
    if c[C_CHG_LC1] != 0.0 or c[C_CHG_LCT] != 0.0:
        s = change_fraction(t, c[C_CHG_T0], c[C_CHG_DT])
        c1 *= math.exp(s * c[C_CHG_LC1])
        ct *= math.exp(s * c[C_CHG_LCT])
    return c1, ct


@njit(cache=True)
def plant_rhs(t, y, p, c, dy, aux):
    """Closed-loop derivatives dy = f(t, y) and the auxiliary outputs (a, u, xv, QL, Ff, ps).

    `p` is the packed vector of `pack(params)`, `c` a drive vector (module docstring).
    """
    x = y[IX]
    v = y[IV]
    pL = y[IPL]
    z = y[IZ]

    # PID (11), derivative on measurement, integral term as state, saturation + anti-windup
    e = c[C_XD] - x
    u_pid = c[C_KP] * e + y[IUI] - c[C_KD] * v
    if c[C_KPL] != 0.0:
        u_pid -= c[C_KPL] * (pL - c[C_PLREF])
    ecc = 0.0
    if c[C_EA] != 0.0:
        ecc = c[C_EA] * math.sin(c[C_EW] * t + c[C_EP])
    if c[C_KFF] != 0.0:  # the load cells' force deviation, fed forward
        u_pid += c[C_KFF] * (c[C_DFL] + ecc)
    u = c[C_PID] * u_pid + c[C_UEXT]
    umax = p[P_UMAX]
    dui = c[C_PID] * c[C_KI] * e
    if u > umax:
        u = umax
        if dui > 0.0:
            dui = 0.0
    elif u < -umax:
        u = -umax
        if dui < 0.0:
            dui = 0.0

    # servo amplifier and valve (2)-(3); orifice flow (1) with pump pulsation and the regularised
    # signed root dp / (dp^2 + dp_reg^2)^(1/4)
    ps_t = supply_pressure(t, p)
    if p[D_VW] > 0.0:  # a valve with dynamics: the spool lags the command (second order)
        wn = p[D_VW]
        xs = y[IXS]
        dy[IXS] = y[IVS]
        dy[IVS] = wn * (wn * (p[D_KXV] * u - xs) - 2.0 * p[P_VZETA] * y[IVS])
        xv = min(max(xs, -p[P_XVMAX]), p[P_XVMAX])
        opening, kq = xv, p[D_KQX]  # the flow's gain per metre of spool
    else:  # the paper's ideal valve: xv = Ksv Kp1 u, at once (bit for bit the paper's loop when xv_max = inf)
        dy[IXS] = 0.0
        dy[IVS] = 0.0
        opening = min(max(u, -p[D_ULIM]), p[D_ULIM])
        xv = p[D_KXV] * opening
        kq = p[D_KQ]  # per volt of command
    dp = ps_t - pL if opening >= 0.0 else pL - p[P_PT]  # towards the supply when opening, the tank when closing
    ql = kq * opening * dp / math.sqrt(math.sqrt(dp * dp + p[D_DPR2]))

    # continuity (4): V = Ap (L1 + x)
    c1, ct = damping_and_leakage(t, p, c)
    dpl = p[D_BA] / (p[P_L1] + x) * (ql - p[P_AP] * v - ct * (pL - p[P_PB]))

    # LuGre friction (5)-(7)
    r = v * p[D_INVVS]
    g = p[P_FC] + p[D_FSC] * math.exp(-r * r)
    dz = v - p[P_S0] * abs(v) * z / g
    ff = p[P_S0] * z + p[P_S1] * dz + p[P_S2] * v

    # force balance (8)
    fl = p[P_FL] + c[C_DFL]
    if c[C_EA] != 0.0:
        fl += ecc
    acc = (p[P_AP] * pL - p[D_ABPB] - c1 * v - p[P_K1] * x - ff - fl) * p[D_INVM]

    dy[IX] = v
    dy[IV] = acc
    dy[IPL] = dpl
    dy[IZ] = dz
    dy[IUI] = dui
    aux[A_ACC] = acc
    aux[A_U] = u
    aux[A_XV] = xv
    aux[A_QL] = ql
    aux[A_FF] = ff
    aux[A_PS] = ps_t


@njit(cache=True)
def state_ok(y, p, p_max):
    """False when the state is non-finite, the piston leaves its stroke [-L1, L-L1] or |pL| > p_max."""
    for i in range(NY):
        if not math.isfinite(y[i]):
            return False
    x = y[IX]
    if x <= -p[P_L1] or x >= p[P_L] - p[P_L1]:
        return False
    return abs(y[IPL]) <= p_max


def drive_vector(gains: PIDGains, xd: float = 0.0, u_ext: float = 0.0, pid_on: bool = True,
                 dFL: float = 0.0, ecc_amp: float = 0.0, ecc_omega: float = 0.0,
                 ecc_phase: float = 0.0, pl_ref: float = 0.0,
                 change: "PlantChange | None" = None) -> np.ndarray:
    """Pack a drive vector (see module docstring); `gains.kpl` is the pressure-feedback gain and
    `gains.kff` the force feedforward gain."""
    c = np.zeros(NC)
    c[C_KP], c[C_KI], c[C_KD], c[C_KPL], c[C_KFF] = gains.kp, gains.ki, gains.kd, gains.kpl, gains.kff
    c[C_XD], c[C_UEXT], c[C_PID] = xd, u_ext, 1.0 if pid_on else 0.0
    c[C_DFL], c[C_EA], c[C_EW], c[C_EP] = dFL, ecc_amp, ecc_omega, ecc_phase
    c[C_PLREF] = pl_ref
    if change is not None:
        change.write(c)
    return c


@dataclass(frozen=True)
class PlantChange:
    """A change of damping and leakage during a run: c1 -> c1 * c1_factor, Ct -> Ct * ct_factor,
    starting at t0_s and completed duration_s later (smoothstep, geometric in the values)."""

    t0_s: float
    duration_s: float
    c1_factor: float = 1.0
    ct_factor: float = 1.0

    def __post_init__(self) -> None:
        for name in ("t0_s", "duration_s", "c1_factor", "ct_factor"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
                    or not math.isfinite(as_float(value)):
                raise ValueError(f"PlantChange.{name} = {shown(value)} is invalid: must be a finite number")
        if self.t0_s < 0 or self.duration_s <= 0:
            raise ValueError(f"PlantChange: t0_s = {shown(self.t0_s)} must be >= 0 and duration_s = "
                             f"{shown(self.duration_s)} > 0 (s)")
        if self.c1_factor <= 0 or self.ct_factor <= 0:
            raise ValueError(f"PlantChange: c1_factor = {shown(self.c1_factor)} and ct_factor = "
                             f"{shown(self.ct_factor)} must be > 0")

    def write(self, c: np.ndarray) -> None:
        c[C_CHG_T0], c[C_CHG_DT] = self.t0_s, self.duration_s
        c[C_CHG_LC1], c[C_CHG_LCT] = math.log(self.c1_factor), math.log(self.ct_factor)

    def values_at(self, t: float, params: MillParams) -> tuple[float, float]:
        """(c1, Ct) at time t, from the same ramp the plant integrates."""
        s = change_fraction(float(t), self.t0_s, self.duration_s)
        return (params.c1 * math.exp(s * math.log(self.c1_factor)),
                params.Ct * math.exp(s * math.log(self.ct_factor)))


#: a servo valve's catalogue rating: the flow at the rated command (10 V, full spool stroke) and a
#: 7 MPa (70 bar) pressure drop across the valve, the usual datasheet condition
RATED_COMMAND_V = 10.0
RATED_DROP_PA = 7.0e6


def rated_flow(params: MillParams) -> float:
    """The valve's rated flow (m^3/s): orifice equation (1) at the rated command's opening
    (Ksv Kp1 x 10 V, within the spool stroke) and the rated drop. 2.5e-3 m^3/s (149 L/min) for Table 1."""
    opening = min(params.xv_per_volt * RATED_COMMAND_V, params.xv_max)
    return params.Cd * params.W * opening * math.sqrt(2.0 / params.rho) * math.sqrt(RATED_DROP_PA)


@njit(cache=True)
def balanced_pressure(y: np.ndarray, p: np.ndarray, c: np.ndarray, t: float = 0.0) -> float:
    """Chamber pressure pL that gives zero acceleration in state y (Eq. 8 is linear in pL).

    Solved with `plant_rhs` itself (two evaluations), so the force balance is written only once. NaN where no
    pressure does it at float64's resolution (`held_pressure` says so in one line).
    """
    dy, aux = np.empty(NY), np.empty(NAUX)
    ya, yb = y.copy(), y.copy()
    ya[IPL], yb[IPL] = 0.0, p[P_PS]
    plant_rhs(t, ya, p, c, dy, aux)
    acc_a = dy[IV]
    plant_rhs(t, yb, p, c, dy, aux)
    den = dy[IV] - acc_a
    return -acc_a * p[P_PS] / den if den != 0.0 else math.nan


def held_pressure(y: np.ndarray, p: np.ndarray, c: np.ndarray) -> float:
    """`balanced_pressure`, or a ValueError of one line where no chamber pressure holds the mill still at float64's
    resolution: the pressure's force lost beside the others, parameters of no mill (k1 = 1e30, FL = 1e30, ps =
    1e-30 Pa)."""
    pl = balanced_pressure(y, p, c)
    if not math.isfinite(pl):
        raise ValueError(f"no chamber pressure holds the mill still at x = {y[IX]:.4g} m: the pressure's force "
                         f"(ps Ap = {p[P_PS] * p[P_AP]:.3g} N) is lost beside the others (k1 x = "
                         f"{p[P_K1] * y[IX]:.3g}, FL = {p[P_FL] + c[C_DFL]:.3g}, pb Ab = {p[P_PB] * p[P_AB]:.3g}, "
                         f"fs = {p[P_FS]:.3g} N); allowed: parameters whose forces float64 can add")
    return pl


def initial_state(params: MillParams, x0: float = 1.0e-3, uI0: float = 0.0) -> np.ndarray:
    """The paper's initial state X00 = [x0, 0, 0]: at rest, zero acceleration, bristles at fs.

    At v = 0 the paper takes the friction force to be fs, so z0 = fs / sigma0, and zero
    acceleration fixes pL0 through the force balance (8).
    """
    y0 = np.zeros(NY)
    y0[IX] = x0
    y0[IZ] = params.fs / params.sigma0
    y0[IUI] = uI0
    y0[IPL] = held_pressure(y0, pack(params), np.zeros(NC))
    return y0


@lru_cache(maxsize=64)
def _resting_pack(params: MillParams) -> np.ndarray:
    """`pack` of `params` with the spool at its command (no valve dynamics, no stroke limit): what `settled_state`
    solves on, kept per plant (the MPC bounds linearise one plant some 16 times an episode on the start ramp).
    Shared: read it, never write it."""
    return pack(params.replace(valve_wn_hz=0.0, xv_max=math.inf))


def settled_state(params: MillParams, xd: float = 0.0, dFL: float = 0.0, z: float = 0.0) -> np.ndarray:
    """Steady operation at the set-point: x = xd, at rest, bristles at z (default relaxed, 0), pL
    holding the load (force balance 8) and the integral term uI feeding the leak (continuity 4:
    QL = Ct (pL - pb)).

    Both unknowns come from `plant_rhs` itself: pL through `balanced_pressure`, uI because the
    pressure rate is linear in the valve command on either side of u = 0. The supply pressure is
    its mean (the pulsation's phase is zero at t = 0). A valve with dynamics starts with its spool
    at the opening that holds the leak (the command solved with the ideal valve's equations).
    """
    p = _resting_pack(params)
    c = np.zeros(NC)
    c[C_KP], c[C_PID], c[C_XD], c[C_DFL] = 1.0, 1.0, xd, dFL  # e = 0: the gain plays no part
    y = np.zeros(NY)
    y[IX] = xd
    y[IZ] = z
    y[IPL] = held_pressure(y, p, c)
    dy, aux = np.empty(NY), np.empty(NAUX)
    plant_rhs(0.0, y, p, c, dy, aux)
    leak_rate = dy[IPL]  # uI = 0: only the leak acts
    side = 1.0 if leak_rate <= 0.0 else -1.0  # the valve must open towards the supply (or the tank)
    y[IUI] = side
    plant_rhs(0.0, y, p, c, dy, aux)
    y[IUI] = -leak_rate * side / (dy[IPL] - leak_rate) if dy[IPL] != leak_rate else 0.0
    if not params.ideal_valve:
        y[IXS] = min(max(params.xv_per_volt * min(max(y[IUI], -params.u_max), params.u_max),
                         -params.xv_max), params.xv_max)
    return y
