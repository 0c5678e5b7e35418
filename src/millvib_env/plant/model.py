"""The plant's equations, once: the closed-loop right-hand side every integrator calls.

State vector ``y`` (``NY = 5``), SI units:

=====  ======  ===========================================================
index  name    meaning
=====  ======  ===========================================================
0      x       piston displacement (m), positive = extending (pressing)
1      v       piston velocity (m/s)
2      pL      rod-less chamber pressure (Pa)
3      z       LuGre mean bristle deflection (m)
4      uI      PID integral term (V): d(uI)/dt = KI * e
=====  ======  ===========================================================

Drive vector ``c`` (``NC``), held constant over an integration segment:
KP, KI, KD (PID gains), xd (set-point, m), u_ext (external valve command, V, added to the PID
output), pid_on (1.0 or 0.0), dFL (rolling-force offset, N), eccentricity force amplitude (N),
angular frequency (rad/s) and phase (rad).

Equations (paper numbering):

* (11) PID:  u = pid_on * (KP e + uI - KD v) + u_ext,  e = xd - x, saturated at +-u_max.
  The derivative acts on the measurement (-KD v), so a set-point step gives no derivative kick.
  Storing the integral *term* uI (not int e) makes gain changes bumpless in the integral term.
  Integration stops while the output saturates in the direction of e (anti-windup).
* (2)-(3) servo amplifier and valve:  xv = Ksv Kp1 u.
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

import numpy as np
from numba import njit

from millvib_env.params import PARAM_FIELDS, MillParams, PIDGains

# --- layout of the vectors the compiled code reads ---------------------------------------------
NY = 5
IX, IV, IPL, IZ, IUI = range(NY)
STATE_NAMES = ("x", "v", "pL", "z", "uI")

_P = {name: i for i, name in enumerate(PARAM_FIELDS)}
NP = len(PARAM_FIELDS)
P_AP, P_AB, P_MT, P_C1, P_K1, P_FL, P_CT = (_P[k] for k in ("Ap", "Ab", "mt", "c1", "k1", "FL", "Ct"))
P_PS, P_PT, P_PB, P_BETA, P_RHO, P_CD, P_W = (_P[k] for k in ("ps", "pt", "pb", "beta_e", "rho", "Cd", "W"))
P_KP1, P_KSV, P_L1, P_L = (_P[k] for k in ("Kp1", "Ksv", "L1", "L"))
P_S0, P_S1, P_S2, P_FC, P_FS, P_VS = (_P[k] for k in ("sigma0", "sigma1", "sigma2", "fc", "fs", "vs"))
P_PA, P_PF, P_PH2, P_PH3, P_DPR, P_UMAX = (
    _P[k] for k in ("pulse_amp", "pulse_freq", "pulse_h2", "pulse_h3", "dp_reg", "u_max"))

NC = 10
C_KP, C_KI, C_KD, C_XD, C_UEXT, C_PID, C_DFL, C_EA, C_EW, C_EP = range(NC)

NAUX = 6
A_ACC, A_U, A_XV, A_QL, A_FF, A_PS = range(NAUX)
AUX_NAMES = ("a", "u", "xv", "QL", "Ff", "ps")


# derived coefficients, appended to the parameter vector by `pack` (computed once per plant)
ND = 9
D_KQ, D_DPR2, D_BA, D_W, D_INVVS, D_FSC, D_ABPB, D_INVM, D_KXV = range(NP, NP + ND)
NPACK = NP + ND


def pack(params: MillParams) -> np.ndarray:
    """The vector `plant_rhs` reads: MillParams fields (order `PARAM_FIELDS`) + derived constants."""
    p = np.empty(NPACK)
    p[:NP] = params.to_array()
    p[D_KQ] = params.Cd * params.W * math.sqrt(2.0 / params.rho) * params.Ksv * params.Kp1
    p[D_DPR2] = params.dp_reg ** 2
    p[D_BA] = params.beta_e / params.Ap
    p[D_W] = 2.0 * math.pi * params.pulse_freq
    p[D_INVVS] = 1.0 / params.vs
    p[D_FSC] = params.fs - params.fc
    p[D_ABPB] = params.Ab * params.pb
    p[D_INVM] = 1.0 / params.mt
    p[D_KXV] = params.Ksv * params.Kp1
    return p


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
    u = c[C_PID] * (c[C_KP] * e + y[IUI] - c[C_KD] * v) + c[C_UEXT]
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

    # servo amplifier and valve (2)-(3): xv = Ksv Kp1 u; orifice flow (1) with pump pulsation and
    # the regularised signed root dp / (dp^2 + dp_reg^2)^(1/4)
    ps_t = supply_pressure(t, p)
    if u >= 0.0:
        dp = ps_t - pL
    else:
        dp = pL - p[P_PT]
    ql = p[D_KQ] * u * dp / math.sqrt(math.sqrt(dp * dp + p[D_DPR2]))

    # continuity (4): V = Ap (L1 + x)
    dpl = p[D_BA] / (p[P_L1] + x) * (ql - p[P_AP] * v - p[P_CT] * (pL - p[P_PB]))

    # LuGre friction (5)-(7)
    r = v * p[D_INVVS]
    g = p[P_FC] + p[D_FSC] * math.exp(-r * r)
    dz = v - p[P_S0] * abs(v) * z / g
    ff = p[P_S0] * z + p[P_S1] * dz + p[P_S2] * v

    # force balance (8)
    fl = p[P_FL] + c[C_DFL]
    if c[C_EA] != 0.0:
        fl += c[C_EA] * math.sin(c[C_EW] * t + c[C_EP])
    acc = (p[P_AP] * pL - p[D_ABPB] - p[P_C1] * v - p[P_K1] * x - ff - fl) * p[D_INVM]

    dy[IX] = v
    dy[IV] = acc
    dy[IPL] = dpl
    dy[IZ] = dz
    dy[IUI] = dui
    aux[A_ACC] = acc
    aux[A_U] = u
    aux[A_XV] = p[D_KXV] * u
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
                 ecc_phase: float = 0.0) -> np.ndarray:
    """Pack a drive vector (see module docstring)."""
    c = np.zeros(NC)
    c[C_KP], c[C_KI], c[C_KD] = gains.kp, gains.ki, gains.kd
    c[C_XD], c[C_UEXT], c[C_PID] = xd, u_ext, 1.0 if pid_on else 0.0
    c[C_DFL], c[C_EA], c[C_EW], c[C_EP] = dFL, ecc_amp, ecc_omega, ecc_phase
    return c


def balanced_pressure(y: np.ndarray, p: np.ndarray, c: np.ndarray, t: float = 0.0) -> float:
    """Chamber pressure pL that gives zero acceleration in state y (Eq. 8 is linear in pL).

    Solved with `plant_rhs` itself (two evaluations), so the force balance is written only once.
    """
    dy, aux = np.empty(NY), np.empty(NAUX)
    ya, yb = y.copy(), y.copy()
    ya[IPL], yb[IPL] = 0.0, p[P_PS]
    plant_rhs(t, ya, p, c, dy, aux)
    acc_a = dy[IV]
    plant_rhs(t, yb, p, c, dy, aux)
    return -acc_a * p[P_PS] / (dy[IV] - acc_a)


def initial_state(params: MillParams, x0: float = 1.0e-3, uI0: float = 0.0) -> np.ndarray:
    """The paper's initial state X00 = [x0, 0, 0]: at rest, zero acceleration, bristles at fs.

    At v = 0 the paper takes the friction force to be fs, so z0 = fs / sigma0, and zero
    acceleration fixes pL0 through the force balance (8).
    """
    y0 = np.zeros(NY)
    y0[IX] = x0
    y0[IZ] = params.fs / params.sigma0
    y0[IUI] = uI0
    y0[IPL] = balanced_pressure(y0, pack(params), np.zeros(NC))
    return y0
