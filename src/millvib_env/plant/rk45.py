"""scipy's RK45 (Dormand-Prince 5(4), MATLAB's ode45 pair) step for step, compiled around `model.plant_rhs`.

The solver study (`analysis.solver_study`) asks what ode45's tolerances do to the paper's cases. Its object is
the method and its step control, which scipy's `RK45` stands for; driven by `solve_ivp` it calls the plant's
equations from Python at every stage, and that was most of `millvib reproduce`'s time. This is the same
algorithm in compiled code, as scipy 1.17 writes it:

* the tableau, error estimator and quartic dense output of `scipy.integrate.RK45` (a test holds these
  coefficients equal to scipy's);
* its first step (`select_initial_step`, Hairer, Norsett and Wanner II.4, error order 4);
* its step control: the RMS norm of the error over ``atol + max(|y|, |y_new|) rtol``, a factor of
  0.9 err^(-1/5) within [0.2, 10], no growth right after a rejection, `max_step` and scipy's minimum step;
* `solve_ivp`'s samples: each output time in (t_old, t] from that step's dense output, and its count of
  right-hand-side evaluations (`nfev`).

The operations are the same; their rounding is not (a compiled loop sums in another order than numpy's BLAS
products), so the two agree to rounding over a short run and, where the loop is sensitive to rounding, may part
after many steps, as two processors would. `tests/test_integrate.py` checks it against scipy's `solve_ivp`.

A segment that leaves the physical envelope, meets a non-finite error or is refused a step is not finished
here: the kernel says so, and the caller runs that segment with `solve_ivp` and its event location
(`integrate._reference_one`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from millvib_env.plant.model import IPL, IX, NAUX, NY, plant_rhs

__all__ = ["A", "B", "C", "E", "P", "rk45_segment", "DONE", "HANDED_BACK"]

DONE, HANDED_BACK = 0, 1

# scipy.integrate.RK45's coefficients, written as scipy writes them (the same floats)
C = np.array([0, 1/5, 3/10, 4/5, 8/9, 1])
A = np.array([
    [0, 0, 0, 0, 0],
    [1/5, 0, 0, 0, 0],
    [3/40, 9/40, 0, 0, 0],
    [44/45, -56/15, 32/9, 0, 0],
    [19372/6561, -25360/2187, 64448/6561, -212/729, 0],
    [9017/3168, -355/33, 46732/5247, 49/176, -5103/18656]
])
B = np.array([35/384, 0, 500/1113, 125/192, -2187/6784, 11/84])
E = np.array([-71/57600, 0, 71/16695, -71/1920, 17253/339200, -22/525, 1/40])
P = np.array([
    [1, -8048581381/2820520608, 8663915743/2820520608, -12715105075/11282082432],
    [0, 0, 0, 0],
    [0, 131558114200/32700410799, -68118460800/10900136933, 87487479700/32700410799],
    [0, -1754552775/470086768, 14199869525/1410260304, -10690763975/1880347072],
    [0, 127303824393/49829197408, -318862633887/49829197408, 701980252875 / 199316789632],
    [0, -282668133/205662961, 2019193451/616988883, -1453857185/822651844],
    [0, 40617522/29380423, -110615467/29380423, 69997945/29380423]])

_N_STAGES = 6
_ERROR_ORDER = 4
_SAFETY, _MIN_FACTOR, _MAX_FACTOR = 0.9, 0.2, 10.0


@njit(cache=True)
def _rms(v, n):
    s = 0.0
    for i in range(n):
        s += v[i] * v[i]
    return math.sqrt(s) / n ** 0.5


@njit(cache=True)
def _envelope(y, lo, hi, p_max):
    """solve_ivp's terminal event in the reference (> 0 inside): stroke margins and the pressure margin."""
    return min(y[IX] - lo, hi - y[IX], (p_max - abs(y[IPL])) * 1e-9)


@njit(cache=True)
def _first_step(t0, y0, f0, t_bound, max_step, rtol, atol, p, c, aux):
    """scipy's `select_initial_step` for an error estimator of order 4; returns (h_abs, 1 evaluation)."""
    interval = abs(t_bound - t0)
    if interval == 0.0:
        return 0.0
    n = y0.shape[0]
    sc = np.empty(n)
    v = np.empty(n)
    for i in range(n):
        sc[i] = atol[i] + abs(y0[i]) * rtol
    for i in range(n):
        v[i] = y0[i] / sc[i]
    d0 = _rms(v, n)
    for i in range(n):
        v[i] = f0[i] / sc[i]
    d1 = _rms(v, n)
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h0 = min(h0, interval)
    y1 = np.empty(n)
    for i in range(n):
        y1[i] = y0[i] + h0 * f0[i]
    f1 = np.empty(n)
    plant_rhs(t0 + h0, y1, p, c, f1, aux)
    for i in range(n):
        v[i] = (f1[i] - f0[i]) / sc[i]
    d2 = _rms(v, n) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1.0 / (_ERROR_ORDER + 1))
    return min(100 * h0, h1, interval, max_step)


@njit(cache=True, inline="always")
def _rk_step(t, h, y, f, K, yt, y_new, p, c, aux):
    """One Dormand-Prince step of size h from (t, y) with f = f(t, y): K[0] = f, stages 1..5, the fifth-order
    solution into y_new and its derivative into K[6] (FSAL), as scipy's `rk_step`."""
    n = NY
    for i in range(n):
        K[0, i] = f[i]
    for s in range(1, _N_STAGES):
        for i in range(n):
            acc = 0.0
            for j in range(s):
                acc += K[j, i] * A[s, j]
            yt[i] = y[i] + acc * h
        plant_rhs(t + C[s] * h, yt, p, c, K[s], aux)
    for i in range(n):
        acc = 0.0
        for j in range(_N_STAGES):
            acc += K[j, i] * B[j]
        y_new[i] = y[i] + h * acc
    plant_rhs(t + h, y_new, p, c, K[_N_STAGES], aux)


@njit(cache=True, inline="always")
def _error_norm(K, h, y, y_new, atol, rtol, err):
    """The step's error estimate, scaled per state by atol + max(|y|, |y_new|) rtol, as an RMS norm."""
    n = NY
    for i in range(n):
        acc = 0.0
        for j in range(_N_STAGES + 1):
            acc += K[j, i] * E[j]
        err[i] = acc * h / (atol[i] + max(abs(y[i]), abs(y_new[i])) * rtol)
    return _rms(err, n)


@njit(cache=True, inline="always")
def _next_step(h_abs, error_norm, rejected):
    """scipy's step-size control: (the next step's size, whether this step is accepted); a step after a rejection
    does not grow."""
    if error_norm < 1:
        if error_norm == 0:
            factor = _MAX_FACTOR
        else:
            factor = min(_MAX_FACTOR, _SAFETY * error_norm ** (-1.0 / (_ERROR_ORDER + 1)))
        if rejected:
            factor = min(1.0, factor)
        return h_abs * factor, True
    return h_abs * max(_MIN_FACTOR, _SAFETY * error_norm ** (-1.0 / (_ERROR_ORDER + 1))), False


@njit(cache=True, inline="always")
def _dense_output(K, t_old, t, y, t_eval, k_out, out, Q):
    """The samples of `t_eval` in (t_old, t] from the step's quartic dense output, written into `out` from row
    k_out on; returns the next row."""
    n = NY
    n_out = t_eval.shape[0]
    hd = t - t_old
    for i in range(n):  # Q = K.T P
        for m in range(4):
            acc = 0.0
            for j in range(_N_STAGES + 1):
                acc += K[j, i] * P[j, m]
            Q[i, m] = acc
    while k_out < n_out and t_eval[k_out] <= t:
        x = (t_eval[k_out] - t_old) / hd
        x2 = x * x
        x3 = x2 * x
        x4 = x3 * x
        for i in range(n):
            out[k_out, i] = hd * (Q[i, 0] * x + Q[i, 1] * x2 + Q[i, 2] * x3 + Q[i, 3] * x4) + y[i]
        k_out += 1
    return k_out


@njit(cache=True)
def rk45_segment(p, c, y0, t0, t_eval, rtol, atol, max_step, lo, hi, p_max, out):
    """Integrate from (t0, y0) to t_eval[-1] with the drive c held, as `solve_ivp(..., method="RK45",
    t_eval=t_eval)` does; writes out[k] at t_eval[k].

    Returns (code, nfev): `DONE`, or `HANDED_BACK` where the state left the envelope (the event changed
    sign), a step's error was not finite or the step fell below scipy's minimum (the caller then runs the
    segment with `solve_ivp`)."""
    n = NY
    t_bound = t_eval[-1]
    aux = np.empty(NAUX)
    K = np.empty((_N_STAGES + 1, n))
    y = y0.copy()
    y_new = np.empty(n)
    yt = np.empty(n)
    f = np.empty(n)
    err = np.empty(n)
    Q = np.empty((n, 4))
    plant_rhs(t0, y, p, c, f, aux)
    nfev = 1
    g = _envelope(y, lo, hi, p_max)
    if not g > 0.0:
        return HANDED_BACK, nfev
    h_abs = _first_step(t0, y, f, t_bound, max_step, rtol, atol, p, c, aux)
    nfev += 1
    t = t0
    k_out = 0
    n_out = t_eval.shape[0]
    while t != t_bound:
        min_step = 10.0 * abs(np.nextafter(t, np.inf) - t)
        if h_abs > max_step:
            h_abs = max_step
        elif h_abs < min_step:
            h_abs = min_step
        accepted = False
        rejected = False
        h = 0.0
        t_new = t
        while not accepted:
            if h_abs < min_step:
                return HANDED_BACK, nfev
            h = h_abs
            t_new = t + h
            if t_new - t_bound > 0:
                t_new = t_bound
            h = t_new - t
            h_abs = abs(h)
            _rk_step(t, h, y, f, K, yt, y_new, p, c, aux)
            nfev += _N_STAGES
            error_norm = _error_norm(K, h, y, y_new, atol, rtol, err)
            if not math.isfinite(error_norm):
                return HANDED_BACK, nfev
            h_abs, accepted = _next_step(h_abs, error_norm, rejected)
            rejected = rejected or not accepted
        t_old = t
        t = t_new
        # the terminal event: solve_ivp would locate where the state left; the caller's solve_ivp does
        g_new = _envelope(y_new, lo, hi, p_max)
        if not g_new > 0.0:
            return HANDED_BACK, nfev
        # the samples in (t_old, t], from the step's quartic dense output
        if k_out < n_out and t_eval[k_out] <= t:
            k_out = _dense_output(K, t_old, t, y, t_eval, k_out, out, Q)
        for i in range(n):
            y[i] = y_new[i]
            f[i] = K[_N_STAGES, i]
    return DONE, nfev
