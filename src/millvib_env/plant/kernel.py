"""Compiled integration kernels (numba). Every one of them calls `model.plant_rhs`.

The fast scheme is the Bogacki-Shampine 3(2) pair (the method behind MATLAB's ode23): adaptive
step, FSAL (3 new right-hand-side evaluations per step), error per component against
``atol_i + rtol |y_i|``, and cubic Hermite dense output so samples never force small steps. It
was chosen by measurement against a tight LSODA reference over the paper's cases and the
unstable corner (`scripts/integrator_study.py`): fixed-step RK4 needs h <= 6e-6 s at high KP and
still loses the limit cycles (the LuGre bristle rate sigma0 |v| / g(v) reaches 8e5 1/s there),
Dormand-Prince 5(4) is close on smooth cases but slower in the limit cycles (docs/integrator_study.md), and a
Rosenbrock 2(3) pays more for its Jacobian than it saves.

Samples: the kernels write the state at the sample times ``t_base + k dt_s`` that fall in each
integrated interval (cubic Hermite between steps); the auxiliary outputs (a, u, xv, QL, Ff, ps)
come from one `plant_rhs` call at a sampled state, in the kernel or afterwards (`aux_at`).

Threads: a batch deals its plants out in turn (thread j runs plants j, j + T, ...), since a plant's cost varies a
hundredfold and maps list their plants in order. The batch entry points and `aux_at` release the GIL, so a caller
may run a batch on a thread beside Python work (`millvib reproduce` does, for its motion map).

Status codes: 0 ok, 1 left the envelope (non-finite state, stroke limits, |pL| > p_max),
2 step size underflow, 3 step budget exhausted. Codes 1-3 are reported as divergence.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from millvib_env.plant.model import C_DFL, C_XD, D_VW, N_CORE_STATES, NAUX, NY, plant_rhs, state_ok
from millvib_env.threads import numba_threads, use_threads

OK, LEFT_ENVELOPE, STEP_UNDERFLOW, STEP_BUDGET = 0, 1, 2, 3
STATUS_TEXT = {OK: "ok", LEFT_ENVELOPE: "left the physical envelope (non-finite state, stroke or pressure)",
               STEP_UNDERFLOW: "step size underflow", STEP_BUDGET: "step budget exhausted"}

H_MIN = 1e-12  # s
H_INIT = 1e-6  # s, first step of a run (grows by up to 5x per accepted step)


@njit(cache=True)
def _write_sample(t, y0, f0, y1, f1, h, tk, p, c, ys, auxs, k, work, aux, with_aux):
    th = (tk - t) / h
    h00 = (1.0 + 2.0 * th) * (1.0 - th) * (1.0 - th)
    h10 = th * (1.0 - th) * (1.0 - th)
    h01 = th * th * (3.0 - 2.0 * th)
    h11 = th * th * (th - 1.0)
    for i in range(NY):
        ys[k, i] = h00 * y0[i] + h10 * h * f0[i] + h01 * y1[i] + h11 * h * f1[i]
    if with_aux:
        plant_rhs(tk, ys[k], p, c, work, aux)
        for i in range(NAUX):
            auxs[k, i] = aux[i]


@njit(cache=True)
def advance(t, t1, y, f, h, p, c, rtol, atol, p_max, max_steps,  # noqa: C901 (one compiled step loop)
            t_base, dt_s, k, ys, auxs, with_aux):
    """Integrate y from t to t1 with the drive c held constant.

    On entry f must hold f(t, y) (it is updated, FSAL). Samples with index k, k+1, ... and time
    t_base + k dt_s in (t, t1] are written to ys[k] and, if `with_aux`, auxs[k] (while k < len(ys)).
    Returns (t_reached, h_next, k_next, status, n_steps).
    """
    n_s = ys.shape[0]
    k2 = np.empty(NY)
    k3 = np.empty(NY)
    k4 = np.empty(NY)
    yt = np.empty(NY)
    yn = np.empty(NY)
    work = np.empty(NY)
    aux = np.empty(NAUX)
    n_steps = 0
    # the error norm's states: the ideal valve's two spool states stay zero and are left out, so the
    # paper's loop takes exactly the steps it took before the valve's dynamics were added
    n_err = NY if p[D_VW] > 0.0 else N_CORE_STATES
    span = t1 - t
    eps_t = 1e-12 * max(span, dt_s)
    while t < t1 - eps_t:
        if n_steps >= max_steps:
            return t, h, k, 3, n_steps
        hh = h
        last = False
        if t + hh >= t1 - 1e-9 * hh:
            hh = t1 - t
            last = True
        for i in range(NY):
            yt[i] = y[i] + 0.5 * hh * f[i]
        plant_rhs(t + 0.5 * hh, yt, p, c, k2, aux)
        for i in range(NY):
            yt[i] = y[i] + 0.75 * hh * k2[i]
        plant_rhs(t + 0.75 * hh, yt, p, c, k3, aux)
        for i in range(NY):
            yn[i] = y[i] + hh * (2.0 / 9.0 * f[i] + 1.0 / 3.0 * k2[i] + 4.0 / 9.0 * k3[i])
        plant_rhs(t + hh, yn, p, c, k4, aux)
        err = 0.0
        for i in range(n_err):
            ei = hh * (-5.0 / 72.0 * f[i] + 1.0 / 12.0 * k2[i] + 1.0 / 9.0 * k3[i] - 0.125 * k4[i])
            sc = atol[i] + rtol * max(abs(y[i]), abs(yn[i]))
            err += (ei / sc) * (ei / sc)
        err = math.sqrt(err / n_err)
        n_steps += 1
        if err <= 1.0:  # NaN compares False: rejected
            tn = t1 if last else t + hh
            while k < n_s:
                tk = t_base + k * dt_s
                if tk > tn + eps_t:
                    break
                if tk > t - eps_t:
                    _write_sample(t, y, f, yn, k4, hh, min(tk, tn), p, c, ys, auxs, k, work, aux, with_aux)
                k += 1
            if not state_ok(yn, p, p_max):
                for i in range(NY):
                    y[i] = yn[i]
                return tn, hh, k, 1, n_steps
            t = tn
            for i in range(NY):
                y[i] = yn[i]
                f[i] = k4[i]
            fac = 5.0 if err == 0.0 else min(5.0, max(0.2, 0.9 * err ** (-1.0 / 3.0)))
            h_new = hh * fac
            # a step shortened to land on t1 says nothing about the step the dynamics allow
            h = max(h, h_new) if last else h_new
        else:
            h = hh * (0.2 if not math.isfinite(err) else max(0.2, 0.9 * err ** (-1.0 / 3.0)))
            if h < H_MIN:
                return t, h, k, 2, n_steps
    return t, h, k, 0, n_steps


@njit(cache=True)
def simulate_one(p, c0, y0, xd, dt_out, rtol, atol, p_max, max_steps, ys):
    """One plant over the output grid t_k = k dt_out, k < len(xd); xd held (ZOH) per interval.

    Writes states only (the auxiliary outputs follow from them through `aux_at`).

    The integration restarts (fresh FSAL derivative) wherever xd changes, so a set-point step is
    a true discontinuity. Returns (status, t_fail, n_steps); samples after a failure are NaN.
    """
    n = xd.shape[0]
    c = c0.copy()
    y = y0.copy()
    f = np.empty(NY)
    aux = np.empty(NAUX)
    c[C_XD] = xd[0]
    plant_rhs(0.0, y, p, c, f, aux)
    for i in range(NY):
        ys[0, i] = y[i]
    no_aux = np.empty((0, NAUX))
    h = H_INIT
    t = 0.0
    k = 1
    total = 0
    j0 = 0
    while j0 < n - 1:
        j1 = j0 + 1
        while j1 < n - 1 and xd[j1] == xd[j0]:
            j1 += 1
        c[C_XD] = xd[j0]
        if j0 > 0:
            plant_rhs(t, y, p, c, f, aux)
        t, h, k, status, steps = advance(t, j1 * dt_out, y, f, h, p, c, rtol, atol, p_max,
                                         max_steps - total, 0.0, dt_out, k, ys, no_aux, False)
        total += steps
        if status != 0:
            for kk in range(k, n):
                for i in range(NY):
                    ys[kk, i] = np.nan
            return status, t, total
        j0 = j1
    return 0, np.nan, total


@njit(cache=True, nogil=True, parallel=True)
def simulate_batch_parallel(P, C, Y0, XD, dt_out, rtol, ATOL, p_max, max_steps, YS, status, t_fail, n_steps,
                            n_threads):
    """simulate_one for N plants on `n_threads` of numba's threads: thread j runs plants j, j + T, j + 2T, ...

    A plant's cost varies a hundredfold (a limit cycle against a decay), and a map's plants come in order, so
    contiguous halves left one thread with most of the work (the motion map's 252 plants on two threads took half
    as long again; docs/performance.md). Each plant is independent: the numbers do not depend on the order."""
    n = P.shape[0]
    for j in prange(n_threads):
        for b in range(j, n, n_threads):
            status[b], t_fail[b], n_steps[b] = simulate_one(P[b], C[b], Y0[b], XD[b], dt_out, rtol, ATOL[b],
                                                            p_max, max_steps, YS[b])


@njit(cache=True, nogil=True)
def simulate_batch_serial(P, C, Y0, XD, dt_out, rtol, ATOL, p_max, max_steps, YS, status, t_fail, n_steps):
    """simulate_one for N plants in this thread (no thread pool is started)."""
    for b in range(P.shape[0]):
        status[b], t_fail[b], n_steps[b] = simulate_one(P[b], C[b], Y0[b], XD[b], dt_out, rtol, ATOL[b], p_max,
                                                        max_steps, YS[b])


@njit(cache=True)
def advance_one(b, P, C, Y, F, H, T, XD, DFL, dt_sub, spp, rtol, ATOL, p_max, max_steps, YS, AUXS,
                status, n_valid, n_steps):
    """Advance plant b by one agent period of len(XD[b]) sub-intervals of dt_sub seconds each.

    The environments' stepping kernel. The drive C[b] (gains, valve command, eccentricity, plant
    change) is held over the period; xd and the force offset take XD[b, j], DFL[b, j] in
    sub-interval j. Y[b] (state), F[b] (FSAL derivative, recomputed here), H[b] (step size) and
    T[b] (time) are carried from call to call. Writes spp samples per sub-interval: YS[b, 0] and
    AUXS[b, 0] are the state at the start of the period, then k = 1 .. n_sub*spp at
    T[b] + k dt_sub/spp. n_valid[b] counts the samples written (fewer if the plant left its
    envelope: status[b] != 0).
    """
    p = P[b]
    c = C[b]
    y = Y[b]
    f = F[b]
    ys = YS[b]
    auxs = AUXS[b]
    t0 = T[b]
    dt_s = dt_sub / spp
    c[C_XD] = XD[b, 0]
    c[C_DFL] = DFL[b, 0]
    plant_rhs(t0, y, p, c, f, auxs[0])
    for i in range(NY):
        ys[0, i] = y[i]
    scratch = np.empty(NAUX)
    t = t0
    h = H[b]
    k = 1
    total = 0
    st = 0
    for j in range(XD.shape[1]):
        if j > 0 and (XD[b, j] != c[C_XD] or DFL[b, j] != c[C_DFL]):
            c[C_XD] = XD[b, j]
            c[C_DFL] = DFL[b, j]
            plant_rhs(t, y, p, c, f, scratch)
        t, h, k, st, ns = advance(t, t0 + (j + 1) * dt_sub, y, f, h, p, c, rtol, ATOL[b], p_max,
                                  max_steps - total, t0, dt_s, k, ys, auxs, True)
        total += ns
        if st != 0:
            break
    T[b] = t
    H[b] = h
    status[b] = st
    n_valid[b] = k
    n_steps[b] = total


@njit(cache=True, parallel=True)
def advance_batch_parallel(P, C, Y, F, H, T, XD, DFL, active, dt_sub, spp, rtol, ATOL, p_max, max_steps, YS,
                           AUXS, status, n_valid, n_steps):
    """`advance_one` for every active plant, on numba's threads."""
    for b in prange(P.shape[0]):
        if active[b]:
            advance_one(b, P, C, Y, F, H, T, XD, DFL, dt_sub, spp, rtol, ATOL, p_max, max_steps, YS, AUXS,
                        status, n_valid, n_steps)


@njit(cache=True)
def advance_batch_serial(P, C, Y, F, H, T, XD, DFL, active, dt_sub, spp, rtol, ATOL, p_max, max_steps, YS,
                         AUXS, status, n_valid, n_steps):
    """`advance_one` for every active plant, in this thread (no thread pool is started)."""
    for b in range(P.shape[0]):
        if active[b]:
            advance_one(b, P, C, Y, F, H, T, XD, DFL, dt_sub, spp, rtol, ATOL, p_max, max_steps, YS, AUXS,
                        status, n_valid, n_steps)


def simulate_batch_kernel(P, *args) -> None:
    """The batched simulation on threads or serially, as `threads.use_threads` decides."""

    if use_threads(P.shape[0], "simulate"):
        simulate_batch_parallel(P, *args, min(numba_threads(), P.shape[0]))  # type: ignore[call-arg]
    else:
        simulate_batch_serial(P, *args)


def advance_batch(P, *args) -> None:
    """The environments' batched step on threads or serially, as `threads.use_threads` decides."""

    (advance_batch_parallel if use_threads(P.shape[0], "step") else advance_batch_serial)(P, *args)


@njit(cache=True, nogil=True)
def aux_at(T, Y, p, c0, xd):
    """Auxiliary outputs (a, u, xv, QL, Ff, ps) at (t, y) samples, xd per sample; NaN rows stay NaN."""
    n = T.shape[0]
    out = np.full((n, NAUX), np.nan)
    c = c0.copy()
    dy = np.empty(NY)
    aux = np.empty(NAUX)
    for k in range(n):
        if not np.isfinite(Y[k, 0]):
            continue
        c[C_XD] = xd[k]
        plant_rhs(T[k], Y[k], p, c, dy, aux)
        for i in range(NAUX):
            out[k, i] = aux[i]
    return out


@njit(cache=True)
def rhs_into(t, y, p, c, dy, aux):
    """plant_rhs into the caller's dy (and aux): for a solver that calls it from Python per evaluation
    (the reference's odeint), where allocating and returning a new array costs as much as the equations."""
    plant_rhs(t, y, p, c, dy, aux)


@njit(cache=True)
def rhs_vector(t, y, p, c):
    """plant_rhs returning a new derivative array (for scipy's solve_ivp and the linearisation)."""
    dy = np.empty(NY)
    aux = np.empty(NAUX)
    plant_rhs(t, y, p, c, dy, aux)
    return dy


__all__ = ["advance", "advance_one", "advance_batch", "simulate_one", "simulate_batch_kernel", "aux_at",
           "rhs_vector", "rhs_into", "STATUS_TEXT"]
