"""Linearisation of the closed loop and the stability map KP_crit(c1, Ct).

Everything here differentiates the one right-hand side (`plant_rhs`) numerically; no equation is
re-derived. The pump pulsation is a forcing, not part of the autonomous loop, so the operating
point and the Jacobian use the mean supply pressure (pulse_amp = 0).

LuGre friction makes the small-signal picture depend on the motion, so two linearisations are
offered:

* ``friction="stick"``: at rest with relaxed bristles (z = 0). The bristles act as a spring
  sigma0 = 4.4e9 N/m with damping sigma1 + sigma2 in parallel with the load: the *local*
  stability of the resting equilibrium (small disturbances, below a few micrometres).
* ``friction="sliding"``: at the onset of sliding, bristles saturated (z = g(0)/sigma0, v -> 0+;
  the derivative in v is one-sided). The bristle spring drops out and the friction adds only
  sigma2 of damping: the loop that a large disturbance (the paper's 1 mm start) sees.

The stick loop is much stiffer, so KP_crit(stick) > KP_crit(sliding). Between the two the resting
equilibrium is locally stable but a large disturbance grows into a limit cycle (hard excitation).

The operating point holds the PID integral term frozen at its initial value by default: with the
paper's KI = 0.001 V/(m s) it moves by microvolts over a simulated second, so the plant sits at
the proportional-only equilibrium (an offset where the cylinder leaks). ``integral="settled"``
takes the true equilibrium x = xd instead (the one a large KI reaches).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal, Sequence

import numpy as np
from numba import njit

from millvib_env._checks import instance, integer, real, reals, shown
from millvib_env.distributed import run_jobs
from millvib_env.params import MillParams, PIDGains
from millvib_env.plant.kernel import rhs_vector
from millvib_env.plant.model import (A_XV, C_DFL, C_KP, C_XD, IPL, IUI, IV, IX, IXS, IZ, NAUX, NY, STATE_NAMES,
                                     VALVE_STATES, balanced_pressure, drive_vector, pack, plant_rhs, settled_state,
                                     state_scale)

__all__ = ["OperatingPoint", "operating_point", "jacobian", "spectral_abscissa", "critical_kp",
           "stability_map", "StateSpace", "linearize"]

Friction = Literal["stick", "sliding"]


@dataclass(frozen=True)
class OperatingPoint:
    y: np.ndarray  # (x, v, pL, z, uI)
    xd: float
    friction: str
    integral: str

    @property
    def x(self) -> float:
        return float(self.y[IX])

    @property
    def pL(self) -> float:
        return float(self.y[IPL])


@lru_cache(maxsize=64)
def _mean(params: MillParams) -> MillParams:
    """`params` with the mean supply pressure (pulse_amp = 0), kept per plant: a critical-KP search linearises one
    plant some 36 times, and the MPC bounds' start ramp some 16 times an episode (`linearize`)."""
    return params.replace(pulse_amp=0.0)


@lru_cache(maxsize=64)
def _mean_pack(params: MillParams) -> np.ndarray:
    """`pack` of `_mean(params)`, kept per plant. Shared: read it, never write it."""
    return pack(_mean(params))


@lru_cache(maxsize=64)
def _supply_packs(params: MillParams) -> tuple[np.ndarray, np.ndarray]:
    """`pack` of `_mean(params)` with the supply pressure 0.1 % above and below its own: `linearize`'s central
    difference for E's supply column, kept per plant. Shared: read them, never write them."""
    mean, dps = _mean(params), 1e-3 * params.ps
    return pack(mean.replace(ps=params.ps + dps)), pack(mean.replace(ps=params.ps - dps))


@lru_cache(maxsize=64)
def _ideal(params: MillParams) -> MillParams:
    """The plant at rest: the spool sits at its command (no valve dynamics, no stroke limit)."""
    return params.replace(valve_wn_hz=0.0, xv_max=math.inf)


#: the bracket's steps out from its centre, as fractions of the interval (`_operating_root`)
_BRACKET_STEPS = np.logspace(-9, 0, 46)
#: brentq's tolerances and iteration bound for the operating point
_ROOT_XTOL, _ROOT_RTOL, _ROOT_MAXITER = 1e-15, 1e-13, 200
#: `_operating_root`'s outcomes
_FOUND, _NO_BRACKET, _NAN, _NO_CONVERGENCE = 0, 1, 2, 3


@njit(cache=True)
def _flow_residual(value, which, y, p, c):
    """dpL/dt of the loop at rest with state `which` of `y` set to `value` and pL balancing the force (Eq. 8):
    zero at the operating point."""
    yy = y.copy()
    yy[which] = value
    yy[IPL] = balanced_pressure(yy, p, c)
    dy, aux = np.empty(NY), np.empty(NAUX)
    plant_rhs(0.0, yy, p, c, dy, aux)
    return dy[IPL]


@njit(cache=True)
def _sign(v):
    """numpy's sign of a float: -1, 0, 1, or NaN for NaN."""
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return v  # 0.0 or NaN


@njit(cache=True)
def _brent_step(xpre, xcur, xblk, fpre, fcur, fblk, spre, scur, sbis, delta):
    """Brent's next (previous step, step): inverse interpolation where it is a good short step, else bisection."""
    if abs(spre) > delta and abs(fcur) < abs(fpre):
        if xpre == xblk:  # interpolate
            stry = -fcur * (xcur - xpre) / (fcur - fpre)
        else:  # extrapolate
            dpre = (fpre - fcur) / (xpre - xcur)
            dblk = (fblk - fcur) / (xblk - xcur)
            stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
        if 2.0 * abs(stry) < min(abs(spre), 3.0 * abs(sbis) - delta):  # a good short step
            return scur, stry
    return sbis, sbis  # bisect


@njit(cache=True)
def _brentq(which, y, p, c, xa, xb, xtol, rtol, maxiter):
    """Brent's method for the root of `_flow_residual` in [xa, xb], step for step as scipy's `optimize.brentq`
    (its C loop, scipy/optimize/Zeros/brentq.c): (root, outcome)."""
    xpre, xcur = xa, xb
    xblk, fblk, spre, scur = 0.0, 0.0, 0.0, 0.0
    fpre = _flow_residual(xpre, which, y, p, c)
    if math.isnan(fpre):
        return xpre, _NAN
    fcur = _flow_residual(xcur, which, y, p, c)
    if math.isnan(fcur):
        return xcur, _NAN
    if fpre == 0.0:
        return xpre, _FOUND
    if fcur == 0.0:
        return xcur, _FOUND
    for _ in range(maxiter):
        if fpre * fcur < 0.0:
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        delta = (xtol + rtol * abs(xcur)) / 2.0
        sbis = (xblk - xcur) / 2.0
        if fcur == 0.0 or abs(sbis) < delta:
            return xcur, _FOUND
        spre, scur = _brent_step(xpre, xcur, xblk, fpre, fcur, fblk, spre, scur, sbis, delta)
        xpre, fpre = xcur, fcur
        if abs(scur) > delta:
            xcur += scur
        else:
            xcur += delta if sbis > 0.0 else -delta
        fcur = _flow_residual(xcur, which, y, p, c)
        if math.isnan(fcur):
            return xcur, _NAN
    return xcur, _NO_CONVERGENCE


@njit(cache=True)
def _operating_root(which, y, p, c, center, lo, hi, steps):
    """The root of `_flow_residual` in (lo, hi), bracketed by stepping out from `center` on a log scale
    (`steps`: fractions of the interval), then Brent's method: (root, outcome)."""
    f0 = _flow_residual(center, which, y, p, c)
    if f0 == 0.0:
        return center, _FOUND
    s0 = _sign(f0)
    for k in range(steps.shape[0]):
        step = steps[k] * (hi - lo)
        for side in range(2):
            cand = center - step if side == 0 else center + step
            if lo < cand < hi:
                s = _sign(_flow_residual(cand, which, y, p, c))
                if not s == s0:  # NaN on either side counts as a change, as numpy's signs compare
                    a, b = (center, cand) if center < cand else (cand, center)
                    return _brentq(which, y, p, c, a, b, _ROOT_XTOL, _ROOT_RTOL, _ROOT_MAXITER)
    return 0.0, _NO_BRACKET


@njit(cache=True)
def _jacobian_at(y0, p, c, scale, sliding, stick):
    """d f / d y of `plant_rhs` at y0 over all NY states: central differences, one-sided in v when `sliding`;
    `stick` folds the bristle state into x (`_numerical_jacobian`)."""
    J = np.zeros((NY, NY))
    aux = np.empty(NAUX)
    f0, fp, fm = np.empty(NY), np.empty(NY), np.empty(NY)
    plant_rhs(0.0, y0, p, c, f0, aux)
    for j in range(NY):
        d = 1e-6 * scale[j]
        yp = y0.copy()
        yp[j] += d
        plant_rhs(0.0, yp, p, c, fp, aux)
        if sliding and j == IV:
            for i in range(NY):
                J[i, j] = (fp[i] - f0[i]) / d
        else:
            ym = y0.copy()
            ym[j] -= d
            plant_rhs(0.0, ym, p, c, fm, aux)
            for i in range(NY):
                J[i, j] = (fp[i] - fm[i]) / (2 * d)
    if stick:
        for i in range(NY):
            J[i, IX] += J[i, IZ]
    return J


@njit(cache=True)
def _operating_state(which, y, p, c, center, lo, hi, steps, ideal_valve):
    """`y` at the operating point: its state `which` the root of the flow balance (bracketed in (lo, hi) from
    `center`), pL from the force balance and, for a valve with dynamics, the spool at its commanded opening.
    Returns (state, root, outcome)."""
    root, outcome = _operating_root(which, y, p, c, center, lo, hi, steps)
    y_op = y.copy()
    if outcome != _FOUND:
        return y_op, root, outcome
    y_op[which] = root
    y_op[IPL] = balanced_pressure(y_op, p, c)
    if not ideal_valve:
        aux = np.empty(NAUX)
        plant_rhs(0.0, y_op, p, c, np.empty(NY), aux)
        y_op[IXS] = aux[A_XV]
    return y_op, root, outcome


@njit(cache=True)
def _loop_jacobian(y, p_ideal, p_mean, c, lo, hi, steps, ideal_valve, scale, sliding, stick):
    """`operating_point` (the integral frozen, the root in x from the set-point) and `jacobian` there in one call,
    the same operations: a critical-KP search linearises one plant some 36 times. Returns (J over all states,
    root, outcome)."""
    y_op, root, outcome = _operating_state(IX, y, p_ideal, c, c[C_XD], lo, hi, steps, ideal_valve)
    if outcome != _FOUND:
        return np.zeros((NY, NY)), root, outcome
    return _jacobian_at(y_op, p_mean, c, scale, sliding, stick), root, outcome


def _raise_unless_found(outcome: int, root: float) -> None:
    """`_operating_root`'s failures as the errors scipy's brentq (which it follows) raises."""
    if outcome == _NO_BRACKET:
        raise RuntimeError("no operating point found: the valve cannot hold the load against the leakage")
    if outcome == _NAN:
        raise ValueError(f"The function value at x={root} is NaN; solver cannot continue.")
    if outcome == _NO_CONVERGENCE:
        raise RuntimeError(f"Failed to converge after {_ROOT_MAXITER} iterations, value is {root}.")


def operating_point(params: MillParams, gains: PIDGains, xd: float = 0.0, *, friction: Friction = "stick",
                    integral: Literal["frozen", "settled"] = "frozen", uI: float = 0.0) -> OperatingPoint:
    """Equilibrium at rest (v = 0) of the loop with mean supply pressure.

    The force balance fixes pL for a given x; the flow balance (dpL/dt = 0) is then a scalar root:
    in x with the integral term frozen at `uI` (``integral="frozen"``), or in uI with x = xd
    (``"settled"``).
    """
    _check_plant(params, gains)
    xd = _check_xd(params, xd)
    if friction not in ("stick", "sliding"):
        raise ValueError(f"friction = {shown(friction)} is invalid: use 'stick' or 'sliding'")
    if integral not in ("frozen", "settled"):
        raise ValueError(f"integral = {shown(integral)} is invalid: use 'frozen' or 'settled'")
    p_mean = _mean_pack(_ideal(params))  # at rest the spool sits at its command
    c = drive_vector(gains, xd=xd)
    y = np.zeros(NY)
    y[IX], y[IZ], y[IUI] = xd, 0.0 if friction == "stick" else params.fs / params.sigma0, uI
    which = IX if integral == "frozen" else IUI
    center, lo, hi = (xd, -params.L1, params.L - params.L1) if integral == "frozen" else (0.0, -1e6, 1e6)
    y_op, root, outcome = _operating_state(which, y, p_mean, c, center, lo, hi, _BRACKET_STEPS, params.ideal_valve)
    _raise_unless_found(outcome, root)
    return OperatingPoint(y=y_op, xd=xd, friction=friction, integral=integral)


def _numerical_jacobian(p: np.ndarray, c: np.ndarray, y0: np.ndarray, scale: np.ndarray, friction: str) -> np.ndarray:
    """d f / d y of `plant_rhs` (packed plant `p`, drive `c`) at y0 over all NY states (central differences;
    one-sided in v when sliding). Stuck bristles move with the piston (dz/dt = dx/dt = v), so z - x is
    conserved: z is folded into x (the bristle spring then acts on x), which drops the structural zero
    eigenvalue."""
    return _jacobian_at(y0, p, c, scale, friction == "sliding", friction == "stick")


def _check_plant(params, *gains) -> None:
    """`params` a MillParams and, where given, `gains` a PIDGains."""
    instance("params", params, MillParams, "a MillParams")
    for g in gains:
        instance("gains", g, PIDGains, "a PIDGains")


def _check_xd(params: MillParams, xd) -> float:
    """A set-point inside the stroke (-L1, L - L1)."""
    return real("xd", xd, lo=-params.L1, hi=params.L - params.L1, lo_open=True, hi_open=True)


def jacobian(params: MillParams, gains: PIDGains, op: OperatingPoint) -> np.ndarray:
    """Numerical Jacobian of the loop at `op` (central differences; one-sided in v when sliding).

    Returns the matrix over (x, v, pL) plus uI when the integral is settled and KI > 0. The
    bristle state z is eliminated: when stuck it moves with x (folded into x), when sliding its
    row vanishes (saturated bristles).
    """
    _check_plant(params, gains)
    instance("op", op, OperatingPoint, "an OperatingPoint (operating_point(params, gains))")
    J = _numerical_jacobian(_mean_pack(params), drive_vector(gains, xd=op.xd), op.y, _state_scale(params),
                            op.friction)
    return J[_kept(params.ideal_valve, op.integral == "settled" and gains.ki != 0.0)]


@lru_cache(maxsize=4)
def _kept(ideal_valve: bool, with_integral: bool) -> tuple[np.ndarray, ...]:
    """`np.ix_` of the states `jacobian` keeps: all but z, uI unless the integral is settled and acts, and the
    spool's states of an ideal valve. Shared: read it, never write it."""
    keep = [i for i in range(NY)
            if i != IZ and not (i == IUI and not with_integral) and not (i in VALVE_STATES and ideal_valve)]
    return np.ix_(keep, keep)


@lru_cache(maxsize=64)
def _state_scale(params: MillParams) -> np.ndarray:
    """`state_scale` of `params`, kept per plant as `_mean_pack` is. Shared: read it, never write it."""
    return state_scale(params)


@dataclass(frozen=True)
class StateSpace:
    """The open-loop plant linearised at steady operation: dx/dt = A x + B u + E d, y = C x + D u.

    States (x, v, pL, and the spool's xs, vs for a valve with dynamics) are deviations from the
    operating point (m, m/s, Pa, m, m/s); the input is the servo-amplifier command's deviation from
    the one that holds the operating point (V); the outputs are the three measured states. `E` maps
    the disturbances `disturbances` (the rolling force's deviation from FL, N, and the supply
    pressure's from its mean, Pa: the pump's ripple) into the states. `op` is the operating point (its
    uI is the command that feeds the leak). `to_control()` gives a python-control `StateSpace` (without
    E) where that package is installed.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    op: OperatingPoint
    states: tuple[str, ...] = ("x", "v", "pL")
    inputs: tuple[str, ...] = ("u",)
    outputs: tuple[str, ...] = ("x", "v", "pL")
    E: np.ndarray | None = None
    disturbances: tuple[str, ...] = ("force", "supply")

    @property
    def u0(self) -> float:
        """The valve command (V) that holds the operating point."""
        return float(self.op.y[IUI])

    def poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.A)

    def to_control(self):
        try:
            import control
        except ImportError:
            raise ValueError("python-control is not installed: `pip install control`, or use A, B, C, D") from None
        return control.ss(self.A, self.B, self.C, self.D, states=list(self.states), inputs=list(self.inputs),
                          outputs=list(self.outputs))


def linearize(params: MillParams, xd: float = 0.0, *, friction: Friction = "stick",
              du: float | None = None) -> StateSpace:
    """A, B, C, D and E of the open-loop plant (valve command -> position, velocity, pressure) at rest at `xd`.

    The operating point is `plant.model.settled_state` (the load held by pL, the leak fed by the
    command u0) with the mean supply pressure; the matrices are numerical derivatives of the one
    `plant_rhs` with the PID switched off and the command given as an external input. The
    friction linearisation is chosen as for `jacobian` (stick: the bristle spring folded into x;
    sliding: saturated bristles). The orifice's gain differs between opening (towards the supply,
    ps - pL across it) and closing (towards the tank, pL). By default the matrices hold the local slope
    (the side the operating point's opening is on); `du` (V) replaces it by the secant over u0 +- du
    (ideal valve: B; a valve with dynamics: A's column of the spool position, over the opening that
    du commands), which across a small u0 takes both sides. E: central differences in the rolling force
    and the supply pressure.
    """
    _check_plant(params)
    xd = _check_xd(params, xd)
    if friction not in ("stick", "sliding"):
        raise ValueError(f"friction = {shown(friction)} is invalid: use 'stick' or 'sliding'")
    mean = _mean(params)
    y0 = settled_state(mean, xd=xd, z=params.fs / params.sigma0 if friction == "sliding" else 0.0)
    u0 = float(y0[IUI])
    p = _mean_pack(params)

    def c_of(u: float) -> np.ndarray:
        return drive_vector(PIDGains(0.0), xd=xd, u_ext=u, pid_on=False)

    def f_of(u: float):
        c = c_of(u)
        return lambda y: rhs_vector(0.0, y, p, c)

    scale = _state_scale(params)
    J = _numerical_jacobian(p, c_of(u0), y0, scale, friction)
    secant = du is not None
    du = 1e-3 * max(abs(u0), 1.0) if du is None else real("du", du, lo=0.0, lo_open=True, hi=params.u_max)
    b = (f_of(u0 + du)(y0) - f_of(u0 - du)(y0)) / (2 * du)
    if secant and not params.ideal_valve:
        dxs = du * params.xv_per_volt
        yp, ym = y0.copy(), y0.copy()
        yp[IXS] += dxs
        ym[IXS] -= dxs
        J[:, IXS] = (f_of(u0)(yp) - f_of(u0)(ym)) / (2 * dxs)
    keep = [IX, IV, IPL] + ([] if params.ideal_valve else list(VALVE_STATES))
    A = J[np.ix_(keep, keep)]
    B = b[keep][:, None]
    c0 = drive_vector(PIDGains(0.0), xd=xd, u_ext=u0, pid_on=False)
    dF = 1e-3 * params.FL
    e_force = np.zeros(NY)
    for sign in (1.0, -1.0):
        c = c0.copy()
        c[C_DFL] = sign * dF
        e_force += sign * rhs_vector(0.0, y0, p, c) / (2 * dF)
    dps = 1e-3 * params.ps
    p_hi, p_lo = _supply_packs(params)
    e_ps = (rhs_vector(0.0, y0, p_hi, c0) - rhs_vector(0.0, y0, p_lo, c0)) / (2 * dps)
    E = np.column_stack([e_force[keep], e_ps[keep]])
    op = OperatingPoint(y=y0, xd=xd, friction=friction, integral="settled")
    return StateSpace(A=A, B=B, C=np.eye(len(keep))[:3], D=np.zeros((3, 1)), op=op,
                      states=tuple(STATE_NAMES[i] for i in keep), E=E)


def spectral_abscissa(params: MillParams, gains: PIDGains, xd: float = 0.0, *, friction: Friction = "stick",
                      integral: Literal["frozen", "settled"] = "frozen") -> float:
    """Largest real part of the loop's eigenvalues (1/s): < 0 stable, > 0 unstable."""
    op = operating_point(params, gains, xd, friction=friction, integral=integral)
    return float(np.max(np.linalg.eigvals(jacobian(params, gains, op)).real))


def _abscissa_of_log_kp(params: MillParams, ki: float, kd: float, xd: float, friction: Friction):
    """g(log10 KP): `spectral_abscissa` of the loop at that KP (the integral frozen), the same numbers, with what
    does not depend on KP (the packed plants, the drive, the state scale, the kept states) made once; 1.0
    (unstable) where the loop has no operating point."""
    xd = _check_xd(params, xd)
    if friction not in ("stick", "sliding"):
        raise ValueError(f"friction = {shown(friction)} is invalid: use 'stick' or 'sliding'")
    p_ideal, p_mean = _mean_pack(_ideal(params)), _mean_pack(params)
    c = drive_vector(PIDGains(1.0, ki, kd), xd=xd)  # its KP set at each call
    y = np.zeros(NY)
    y[IX], y[IZ] = xd, 0.0 if friction == "stick" else params.fs / params.sigma0
    lo, hi = -params.L1, params.L - params.L1
    scale, kept = _state_scale(params), _kept(params.ideal_valve, False)

    def g(log_kp: float) -> float:
        c[C_KP] = PIDGains(10.0**log_kp, ki, kd).kp
        J, root, outcome = _loop_jacobian(y, p_ideal, p_mean, c, lo, hi, _BRACKET_STEPS, params.ideal_valve, scale,
                                          friction == "sliding", friction == "stick")
        if outcome in (_NO_BRACKET, _NO_CONVERGENCE):
            return 1.0  # no equilibrium: count as unstable
        _raise_unless_found(outcome, root)
        return float(np.max(np.linalg.eigvals(J[kept]).real))

    return g


def critical_kp(params: MillParams, ki: float = 1e-3, kd: float = 0.0, *, friction: Friction = "stick",
                xd: float = 0.0, kp_range: tuple[float, float] = (1e3, 1e10)) -> float:
    """KP (V/m) at which the loop's least-damped eigenvalue crosses into the right half-plane.

    Returns inf if the loop is stable over all of `kp_range`, 0 if unstable at its low end.
    """
    _check_plant(params)
    ki, kd, xd = real("ki", ki, lo=0.0), real("kd", kd, lo=0.0), real("xd", xd)
    kp_lo, kp_hi = reals("kp_range", kp_range, lo=0.0, lo_open=True, min_len=2)[:2]
    g = _abscissa_of_log_kp(params, ki, kd, xd, friction)
    lo, hi = math.log10(kp_lo), math.log10(kp_hi)
    if g(lo) > 0:
        return 0.0
    if g(hi) < 0:
        return math.inf
    # the abscissa can stay near zero for small KP (slow integrator pole): bracket by a scan
    grid = np.linspace(lo, hi, 28)
    vals = [g(v) for v in grid]
    for a, b, va, vb in zip(grid[:-1], grid[1:], vals[:-1], vals[1:]):
        if va < 0 <= vb:
            from scipy import optimize  # here: importing this module (as an environment does) needs no scipy

            return 10.0 ** optimize.brentq(g, a, b, xtol=1e-6)
    return math.inf


def stability_map(c1_values: Sequence[float] | np.ndarray, Ct_values: Sequence[float] | np.ndarray, *,
                  base: MillParams | None = None, ki: float = 1e-3, kd: float = 0.0, friction: Friction = "stick",
                  progress: bool = False, processes: int = 1) -> np.ndarray:
    """KP_crit over a (c1, Ct) grid: array of shape (len(c1_values), len(Ct_values)); the cells in `processes`
    worker processes (each cell is independent: the same numbers as one process)."""
    return stability_maps(c1_values, Ct_values, frictions=(friction,), base=base, ki=ki, kd=kd, progress=progress,
                          processes=processes)[0]


def stability_maps(c1_values: Sequence[float] | np.ndarray, Ct_values: Sequence[float] | np.ndarray, *,
                   frictions: Sequence[Friction] = ("stick", "sliding"), base: MillParams | None = None,
                   ki: float = 1e-3, kd: float = 0.0, progress: bool = False, processes: int = 1) -> np.ndarray:
    """`stability_map` for each of `frictions`, every cell in one pool of `processes` processes: shape
    (len(frictions), len(c1_values), len(Ct_values))."""
    c1_values = reals("c1_values", c1_values, lo=0.0, lo_open=True)
    Ct_values = reals("Ct_values", Ct_values, lo=0.0)
    base = MillParams() if base is None else instance("base", base, MillParams, "None or a MillParams")
    processes = integer("processes", processes, lo=1, hi=1024)
    jobs = [{"params": base.replace(c1=float(c1), Ct=float(ct)), "ki": ki, "kd": kd, "friction": friction}
            for friction in frictions for c1 in c1_values for ct in Ct_values]
    crit = run_jobs(critical_kp, jobs, processes=processes, progress=progress,
                    desc=f"stability map ({', '.join(frictions)})")
    return np.array(crit, dtype=float).reshape(len(frictions), len(c1_values), len(Ct_values))
