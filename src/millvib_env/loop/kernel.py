"""The sampled loop, compiled: sensors, the digital controller and the zero-order hold around the
plant's integrator. Every plant evaluation is `plant.model.plant_rhs`, every integration step
`plant.kernel.advance`; the controller only sets the held command (``u_ext``, with the analog PID
switched off).

Per loop sample, at t_k = t_0 + k dt:

1. the sensors read the plant's state at t_k: position x_m = Q(x + n_x) (noise, then quantised),
   pressure p_m = LP(pL) + n_p and force F_m = LP(FL(t) - FL) + n_F (first-order low-passes sampled
   exactly), n_* Gaussian, drawn for the whole episode at reset from the episode's own stream;
2. the controller: e = xd - x_m, a filtered backward difference v_f of x_m (the derivative on the
   measurement), ``u_req = pid_on (KP e + uI - KD v_f - KPL (p_m - pL_ref) + KFF F_m) + u_agent``,
   ``u = clip(u_req, -u_max, u_max)``; the integral term uI += KI dt e unless the command is
   saturated in e's direction (conditional integration), and kept within +-u_max;
3. the command computed now is applied now (``delay_samples = 0``) or at t_(k+1) (``= 1``) and held
   until the next sample; the plant is integrated over [t_k, t_(k+1)] with it.

Nothing switches inside an integration step: the command changes only at sample instants, where the
integrator restarts its derivative (FSAL), keeping its step size.

The controller's state per environment (`CS_NAMES`) also counts the episode's command statistics.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from millvib_env.loop.settings import LS_FIELDS
from millvib_env.plant.kernel import advance
from millvib_env.plant.model import (C_DFL, C_EA, C_EP, C_EW, C_KD, C_KFF, C_KI, C_KP, C_KPL, C_PID, C_PLREF, C_UEXT,
                                     C_XD, IPL, IX, NY, P_UMAX, plant_rhs)
from millvib_env.threads import use_threads

__all__ = ["CS_NAMES", "NCS", "read_sensors", "pid_law", "controller_sample", "peek_samples", "plant_drive",
           "advance_loop_batch", "start_state"]

#: the digital controller's state and the episode's command statistics, per environment
CS_NAMES = ("uI", "x_prev", "v_filt", "p_filt", "f_filt", "u_pending", "u_applied", "x_meas", "p_meas", "f_meas",
            "u_ctrl", "n_samples", "n_at_limit", "u_abs_max", "u_req_abs_max")
NCS = len(CS_NAMES)
(K_UI, K_XPREV, K_VF, K_PF, K_FF, K_UPEND, K_UAPP, K_XM, K_PM, K_FM, K_UCTRL, K_NS, K_NSAT, K_UMAX,
 K_UREQMAX) = range(NCS)
L_DT, L_DELAY, L_AD, L_XN, L_XRES, L_PN, L_AP, L_FN, L_AF = (LS_FIELDS.index(k) for k in (
    "dt", "delay", "a_deriv", "x_noise", "x_res", "p_noise", "a_p", "f_noise", "a_f"))


def start_state(y0: np.ndarray, force_dev: float, u0: float, u_max: float) -> np.ndarray:
    """The controller's state at an episode's start: its filters at the plant's values, its integral
    term (and the command it holds) at ``u0`` (the command that holds a settled plant; 0 otherwise)."""
    cs = np.zeros(NCS)
    u0 = min(max(u0, -u_max), u_max)
    cs[K_UI] = u0
    cs[K_XPREV] = cs[K_XM] = y0[IX]
    cs[K_PF] = cs[K_PM] = y0[IPL]
    cs[K_FF] = cs[K_FM] = force_dev
    cs[K_UPEND] = cs[K_UAPP] = u0
    return cs


@njit(cache=True)
def plant_drive(c, u):
    """The drive the plant sees under the digital controller: its analog PID off (no gain acts inside the
    plant) and the held command ``u`` (V) as u_ext; set-point, force, eccentricity and plant change as in c."""
    cp = c.copy()
    cp[C_PID] = 0.0
    cp[C_KP] = 0.0
    cp[C_KI] = 0.0
    cp[C_KD] = 0.0
    cp[C_KPL] = 0.0
    cp[C_KFF] = 0.0
    cp[C_UEXT] = u
    return cp


@njit(cache=True)
def read_sensors(t, y, c, cs, ls, xd, dfl, noise):
    """Step 1 of a sample at time t: the sensors' readings (and the derivative's filter) into cs; returns the
    position error xd - x_m."""
    dt = ls[L_DT]
    xm = y[IX] + ls[L_XN] * noise[0]
    if ls[L_XRES] > 0.0:
        xm = ls[L_XRES] * math.floor(xm / ls[L_XRES] + 0.5)
    cs[K_PF] += ls[L_AP] * (y[IPL] - cs[K_PF])
    pm = cs[K_PF] + ls[L_PN] * noise[1]
    force = dfl
    if c[C_EA] != 0.0:
        force += c[C_EA] * math.sin(c[C_EW] * t + c[C_EP])
    cs[K_FF] += ls[L_AF] * (force - cs[K_FF])
    fm = cs[K_FF] + ls[L_FN] * noise[2]
    cs[K_VF] += ls[L_AD] * ((xm - cs[K_XPREV]) / dt - cs[K_VF])
    cs[K_XPREV] = xm
    cs[K_XM], cs[K_PM], cs[K_FM] = xm, pm, fm
    return xd - xm


@njit(cache=True)
def pid_law(c, cs, e):
    """The PID's command (V) on the readings in cs, its integral term as it stands (before this sample's
    integration): KP e + uI - KD v_f - KPL (p_m - pL_ref) + KFF F_m; 0 with the PID off."""
    u_ctrl = 0.0
    if c[C_PID] != 0.0:
        u_ctrl = c[C_KP] * e + cs[K_UI] - c[C_KD] * cs[K_VF]
        if c[C_KPL] != 0.0:
            u_ctrl -= c[C_KPL] * (cs[K_PM] - c[C_PLREF])
        if c[C_KFF] != 0.0:
            u_ctrl += c[C_KFF] * cs[K_FM]
    return u_ctrl


@njit(cache=True)
def controller_sample(t, y, p, c, cs, ls, xd, dfl, noise):
    """One sample of the digital controller at time t (see the module docstring); returns the command
    to hold from now to the next sample (V)."""
    dt = ls[L_DT]
    # 1. sensors
    e = read_sensors(t, y, c, cs, ls, xd, dfl, noise)
    # 2. the control law, saturation, conditional integration
    u_ctrl = pid_law(c, cs, e)
    cs[K_UCTRL] = u_ctrl
    u_req = u_ctrl + c[C_UEXT]
    umax = p[P_UMAX]
    u = min(max(u_req, -umax), umax)
    if c[C_PID] != 0.0 and c[C_KI] != 0.0:
        di = c[C_KI] * dt * e
        if not ((u_req > umax and di > 0.0) or (u_req < -umax and di < 0.0)):
            cs[K_UI] = min(max(cs[K_UI] + di, -umax), umax)
    # 3. the computation delay, the hold, the episode's statistics
    if ls[L_DELAY] > 0.0:
        out = cs[K_UPEND]
        cs[K_UPEND] = u
    else:
        out = u
    cs[K_UAPP] = out
    cs[K_NS] += 1.0
    if abs(out) >= umax:
        cs[K_NSAT] += 1.0
    cs[K_UMAX] = max(cs[K_UMAX], abs(out))
    cs[K_UREQMAX] = max(cs[K_UREQMAX], abs(u_req))
    return out


@njit(cache=True)
def peek_samples(idx, T, Y, C, CS, LS, xd, dfl, NOISE, k, out):
    """The readings the controller will take at its next sample, without taking them: for environments
    idx[i], at time T, state Y, set-point xd[i], force step dfl[i] and noise row k[i], out[i] = (x_m, v_f,
    p_m, F_m, the PID's command). `read_sensors` and `pid_law` on a copy of the controller's state: the
    same numbers, bit for bit, as the sample that follows reads (an observation taken at the sample)."""
    for i in range(idx.shape[0]):
        b = idx[i]
        cs = CS[b].copy()
        e = read_sensors(T[b], Y[b], C[b], cs, LS, xd[i], dfl[i], NOISE[b, k[i]])
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = cs[K_XM], cs[K_VF], cs[K_PM], cs[K_FM]
        out[i, 4] = pid_law(C[b], cs, e)


@njit(cache=True)
def advance_loop_one(b, P, C, Y, F, H, T, XD, DFL, NOISE, K0, CS, LS, spp, rtol, ATOL, p_max, max_steps, YS, AUXS,
                     status, n_valid, n_steps):
    """Advance plant b by one agent period of len(XD[b]) loop samples (the `plant.kernel.advance_one`
    contract: YS[b, 0] and AUXS[b, 0] the period's start, then spp samples per loop period)."""
    p = P[b]
    c = C[b]
    y = Y[b]
    f = F[b]
    ys = YS[b]
    auxs = AUXS[b]
    cs = CS[b]
    ls = LS
    dt = ls[L_DT]
    dt_s = dt / spp
    t0 = T[b]
    cp = plant_drive(c, cs[K_UAPP])
    cp[C_XD] = XD[b, 0]
    cp[C_DFL] = DFL[b, 0]
    plant_rhs(t0, y, p, cp, f, auxs[0])
    for i in range(NY):
        ys[0, i] = y[i]
    scratch = np.empty(auxs.shape[1])
    t = t0
    h = H[b]
    k = 1
    total = 0
    st = 0
    k0 = K0[b]
    for j in range(XD.shape[1]):
        u = controller_sample(t, y, p, c, cs, ls, XD[b, j], DFL[b, j], NOISE[b, k0 + j])
        cp[C_UEXT] = u
        cp[C_XD] = XD[b, j]
        cp[C_DFL] = DFL[b, j]
        plant_rhs(t, y, p, cp, f, scratch)  # the held command changed: a fresh FSAL derivative
        t, h, k, st, ns = advance(t, t0 + (j + 1) * dt, y, f, h, p, cp, rtol, ATOL[b], p_max, max_steps - total,
                                  t0, dt_s, k, ys, auxs, True)
        total += ns
        if st != 0:
            break
    T[b] = t
    H[b] = h
    status[b] = st
    n_valid[b] = k
    n_steps[b] = total


@njit(cache=True, parallel=True)
def _advance_parallel(P, C, Y, F, H, T, XD, DFL, NOISE, K0, CS, LS, active, spp, rtol, ATOL, p_max, max_steps, YS,
                      AUXS, status, n_valid, n_steps):
    for b in prange(P.shape[0]):
        if active[b]:
            advance_loop_one(b, P, C, Y, F, H, T, XD, DFL, NOISE, K0, CS, LS, spp, rtol, ATOL, p_max, max_steps,
                             YS, AUXS, status, n_valid, n_steps)


@njit(cache=True)
def _advance_serial(P, C, Y, F, H, T, XD, DFL, NOISE, K0, CS, LS, active, spp, rtol, ATOL, p_max, max_steps, YS,
                    AUXS, status, n_valid, n_steps):
    for b in range(P.shape[0]):
        if active[b]:
            advance_loop_one(b, P, C, Y, F, H, T, XD, DFL, NOISE, K0, CS, LS, spp, rtol, ATOL, p_max, max_steps,
                             YS, AUXS, status, n_valid, n_steps)


def advance_loop_batch(P, *args) -> None:
    """`advance_loop_one` for every active plant, on threads or serially as `threads.use_threads` decides."""

    (_advance_parallel if use_threads(P.shape[0], "step") else _advance_serial)(P, *args)
