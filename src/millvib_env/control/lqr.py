"""LQR with integral action for the PID + pressure-feedback structure: the `lqr-oracle` reference.

On the open-loop plant linearised at steady operation (`analysis.linear.linearize`: valve command
-> position, velocity, chamber pressure) augmented with the integral of the position error
xi = int(xd - x) dt, the LQR state feedback u - u0 = -K [x - xd, v, pL - pL0, xi] *is* a PID with
pressure feedback:

    u = KP e + uI - KD v - KPL (pL - pL_ref),   uI = KI xi,
    KP = K_x,  KD = K_v,  KPL = K_p,  KI = -K_xi.

So the reference runs in the gain-schedule environment with its pressure-feedback action, with
gains designed for the episode's true c1 and Ct (an oracle: not deployable). The weights are in
scaled coordinates (x / 10 um, v / 1 mm/s, pL / 1 MPa, xi / (10 um x 10 ms), u / 10 V) and were
tuned per task on its tuning seeds (configs/control/<task>.yaml).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from millvib_env._checks import instance, real, shown
from millvib_env.analysis.linear import Friction, linearize
from millvib_env.threads import one_blas_thread
from millvib_env.params import MillParams

__all__ = ["LQRWeights", "lqr_design", "lqr_gains", "STATE_SCALES", "U_SCALE_V"]

#: scales of (x, v, pL, xi) that make the weights O(1)
STATE_SCALES = np.array([1e-5, 1e-3, 1e6, 1e-7])
U_SCALE_V = 10.0


@dataclass(frozen=True)
class LQRWeights:
    """Diagonal LQR weights in scaled coordinates (see the module docstring) and the friction
    linearisation the design uses ('stick' or 'sliding')."""

    q_x: float = 1.0
    q_v: float = 1.0
    q_p: float = 1e-3
    q_i: float = 1.0
    r: float = 1.0
    friction: Friction = "sliding"

    def __post_init__(self) -> None:
        for name in ("q_x", "q_v", "q_p", "q_i", "r"):
            value = getattr(self, name)
            real(f"LQRWeights.{name}", value, lo=0.0)
        if self.r <= 0:
            raise ValueError(f"LQRWeights.r = {shown(self.r)} is invalid: must be > 0")
        if self.friction not in ("stick", "sliding"):
            raise ValueError(f"LQRWeights.friction = {shown(self.friction)} is invalid: 'stick' or 'sliding'")


def lqr_design(params: MillParams, weights: LQRWeights, xd: float = 0.0, dt_s: float | None = None):
    """(K, A_cl, A_aug, B_aug) of the scaled-coordinate design, K in SI units (V per unit state).

    The model is the plant's linearisation with the paper's ideal valve (the PID + pressure-feedback
    structure has no spool feedback to give) and without the actuator's limits (stroke, amplifier): a plant
    whose leakage takes more than the amplifier's +-u_max to hold (the startup task's high-leakage scenario on
    v1: about 180 V) gets the design of its unlimited linearisation, and runs saturated. With `dt_s` the
    design is discrete-time at that sample period (the loop as commissioned: the augmented model sampled with
    a zero-order hold, and the discrete Riccati equation); A_cl is then the discrete closed loop. The loop's
    computation delay and the valve's lag are not in the model."""
    instance("weights", weights, LQRWeights, "an LQRWeights")
    instance("params", params, MillParams, "a MillParams")
    if dt_s is not None:
        dt_s = real("dt_s", dt_s, lo=0.0, lo_open=True, hi=1.0)
    # the design model is the plant without the actuator's limits (the spool's stroke and the amplifier's
    # +-u_max): a leaky plant held by more than u_max would otherwise linearise with no input at all
    ss = linearize(params.replace(valve_wn_hz=0.0, xv_max=math.inf, u_max=math.inf), xd, friction=weights.friction)
    A = np.zeros((4, 4))
    A[:3, :3] = ss.A
    A[3, 0] = -1.0  # d xi / dt = e = -(x - xd)
    B = np.zeros((4, 1))
    B[:3] = ss.B
    T = STATE_SCALES
    A_s = A * T[None, :] / T[:, None]
    B_s = B * U_SCALE_V / T[:, None]
    Q = np.diag([weights.q_x, weights.q_v, weights.q_p, weights.q_i])
    R = np.array([[weights.r]])
    from scipy import linalg  # here: an environment (whose registry lists this builder) need not import scipy

    with one_blas_thread():  # a 4 x 4 Riccati solve: BLAS threads cost 20x more than they give under load
        if dt_s is None:
            P = linalg.solve_continuous_are(A_s, B_s, Q, R)
            K_s = np.linalg.solve(R, B_s.T @ P)
        else:  # sampled with a zero-order hold: the exponential of [[A, B], [0, 0]] dt
            n = A_s.shape[0]
            M = np.zeros((n + 1, n + 1))
            M[:n, :n], M[:n, n:] = A_s, B_s
            E = linalg.expm(M * dt_s)
            A_s, B_s = E[:n, :n], E[:n, n:]
            P = linalg.solve_discrete_are(A_s, B_s, Q * dt_s, R * dt_s)
            K_s = np.linalg.solve(R * dt_s + B_s.T @ P @ B_s, B_s.T @ P @ A_s)
    K = (U_SCALE_V * K_s / T[None, :])[0]
    if dt_s is None:
        return K, A - B @ K[None, :], A, B
    A_d, B_d = A_s * T[:, None] / T[None, :], B_s * T[:, None] / U_SCALE_V
    return K, A_d - B_d @ K[None, :], A_d, B_d


def lqr_gains(params: MillParams, weights: LQRWeights, xd: float = 0.0, dt_s: float | None = None) -> np.ndarray:
    """(KP, KI, KD, KPL) of the LQR design for `params` (discrete-time at `dt_s` where given); KP may be
    negative (see `LQRPolicy`)."""
    K, _, _, _ = lqr_design(params, weights, xd, dt_s)
    return np.array([K[0], -K[3], K[1], K[2]])
