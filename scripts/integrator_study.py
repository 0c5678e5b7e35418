"""How the fast integrator was chosen: candidate schemes against a tight LSODA reference.

    python scripts/integrator_study.py        # ~1 minute

Every candidate calls the one right-hand side (`plant_rhs`); only the stepping differs. Cases: the
paper's nominal plant, its high-leakage and highest-gain cases, and a limit cycle (c1 = 1.25e5,
KP = 4e6), 0.5 s each, sampled at 10 kHz. Printed per scheme: error against LSODA at rtol 1e-10 as a
fraction of the peak |x| (inf: the scheme blew up), steps, right-hand-side evaluations, wall time.

* RK4 at fixed steps h = 1e-4 / m;
* Dormand-Prince 5(4), adaptive, cubic Hermite output;
* Bogacki-Shampine 3(2), adaptive, cubic Hermite output: the shipped kernel (`simulate`);
* Rosenbrock 2(3) (Shampine's ode23s, L-stable), Jacobian by forward differences every step.
"""

from __future__ import annotations

import math
import time

import numpy as np
from numba import njit

from millvib_env import MillParams, PIDGains
from millvib_env.plant.integrate import simulate, state_scale
from millvib_env.plant.model import NAUX, NY, drive_vector, initial_state, pack, plant_rhs


@njit(cache=True)
def rk4(y0, p, c, dt_out, n_out, m):
    out = np.empty((n_out, NY))
    y = y0.copy()
    h = dt_out / m
    k1, k2, k3, k4, yt, aux = (np.empty(NY), np.empty(NY), np.empty(NY), np.empty(NY), np.empty(NY),
                               np.empty(NAUX))
    for k in range(n_out):
        out[k] = y
        for j in range(m):
            t = (k * m + j) * h
            plant_rhs(t, y, p, c, k1, aux)
            for i in range(NY):
                yt[i] = y[i] + 0.5 * h * k1[i]
            plant_rhs(t + 0.5 * h, yt, p, c, k2, aux)
            for i in range(NY):
                yt[i] = y[i] + 0.5 * h * k2[i]
            plant_rhs(t + 0.5 * h, yt, p, c, k3, aux)
            for i in range(NY):
                yt[i] = y[i] + h * k3[i]
            plant_rhs(t + h, yt, p, c, k4, aux)
            for i in range(NY):
                y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    return out, n_out * m, 4 * n_out * m


# Dormand-Prince 5(4) tableau
A = np.zeros((7, 7))
A[1, 0] = 1 / 5
A[2, :2] = (3 / 40, 9 / 40)
A[3, :3] = (44 / 45, -56 / 15, 32 / 9)
A[4, :4] = (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729)
A[5, :5] = (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656)
A[6, :6] = (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84)
CN = np.array([0.0, 0.2, 0.3, 0.8, 8 / 9, 1.0, 1.0])
E = np.array([71 / 57600, 0.0, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40])


@njit(cache=True)
def dp54(y0, p, c, dt_out, n_out, rtol, atol, A, CN, E):
    out = np.empty((n_out, NY))
    y = y0.copy()
    K = np.empty((7, NY))
    yt, aux = np.empty(NY), np.empty(NAUX)
    t, h, steps, nf, kout = 0.0, 1e-6, 0, 1, 1
    plant_rhs(t, y, p, c, K[0], aux)
    out[0] = y
    while kout < n_out:
        for s in range(1, 7):
            for i in range(NY):
                acc = 0.0
                for j in range(s):
                    acc += A[s, j] * K[j, i]
                yt[i] = y[i] + h * acc
            plant_rhs(t + CN[s] * h, yt, p, c, K[s], aux)
        nf += 6
        steps += 1
        err = 0.0
        for i in range(NY):
            e = 0.0
            for j in range(7):
                e += E[j] * K[j, i]
            sc = atol[i] + rtol * max(abs(y[i]), abs(yt[i]))
            err += (h * e / sc) ** 2
        err = math.sqrt(err / NY)
        if err <= 1.0:
            tn = t + h
            while kout < n_out and kout * dt_out <= tn + 1e-15:
                th = (kout * dt_out - t) / h
                h00, h10 = (1 + 2 * th) * (1 - th) ** 2, th * (1 - th) ** 2
                h01, h11 = th * th * (3 - 2 * th), th * th * (th - 1)
                for i in range(NY):
                    out[kout, i] = h00 * y[i] + h10 * h * K[0, i] + h01 * yt[i] + h11 * h * K[6, i]
                kout += 1
            t = tn
            for i in range(NY):
                y[i] = yt[i]
                K[0, i] = K[6, i]
            h *= min(5.0, max(0.2, 0.9 * err ** -0.2)) if err > 0 else 5.0
        else:
            h *= max(0.2, 0.9 * err ** -0.2) if math.isfinite(err) else 0.2
    return out, steps, nf


D = 1.0 / (2.0 + math.sqrt(2.0))
E32 = 6.0 + math.sqrt(2.0)


@njit(cache=True)
def ros23(y0, p, c, dt_out, n_out, rtol, atol):  # noqa: C901 (one compiled step loop)
    out = np.empty((n_out, NY))
    y = y0.copy()
    aux = np.empty(NAUX)
    F0, F1, F2, ft, T = np.empty(NY), np.empty(NY), np.empty(NY), np.empty(NY), np.empty(NY)
    J = np.empty((NY, NY))
    k1, k2, k3, yt, yn = np.empty(NY), np.empty(NY), np.empty(NY), np.empty(NY), np.empty(NY)
    t, h, steps, nf, kout = 0.0, 1e-6, 0, 1, 1
    plant_rhs(t, y, p, c, F0, aux)
    out[0] = y
    while kout < n_out:
        for j in range(NY):
            dj = 1e-7 * max(abs(y[j]), 1e3 * atol[j] / rtol * 1e-6)
            for i in range(NY):
                yt[i] = y[i]
            yt[j] += dj
            plant_rhs(t, yt, p, c, ft, aux)
            for i in range(NY):
                J[i, j] = (ft[i] - F0[i]) / dj
        plant_rhs(t + 1e-9, y, p, c, ft, aux)
        for i in range(NY):
            T[i] = (ft[i] - F0[i]) / 1e-9
        nf += NY + 1
        while True:
            W = np.eye(NY) - h * D * J
            k1[:] = np.linalg.solve(W, F0 + h * D * T)
            for i in range(NY):
                yt[i] = y[i] + 0.5 * h * k1[i]
            plant_rhs(t + 0.5 * h, yt, p, c, F1, aux)
            k2[:] = np.linalg.solve(W, F1 - k1) + k1
            for i in range(NY):
                yn[i] = y[i] + h * k2[i]
            plant_rhs(t + h, yn, p, c, F2, aux)
            k3[:] = np.linalg.solve(W, F2 - E32 * (k2 - F1) - 2.0 * (k1 - F0) + h * D * T)
            nf += 2
            steps += 1
            err = 0.0
            for i in range(NY):
                e = h / 6.0 * (k1[i] - 2.0 * k2[i] + k3[i])
                err += (e / (atol[i] + rtol * max(abs(y[i]), abs(yn[i])))) ** 2
            err = math.sqrt(err / NY)
            if err <= 1.0:
                tn = t + h
                while kout < n_out and kout * dt_out <= tn + 1e-15:
                    s = (kout * dt_out - t) / h
                    a1, a2 = s * (1 - s) / (1 - 2 * D), s * (s - 2 * D) / (1 - 2 * D)
                    for i in range(NY):
                        out[kout, i] = y[i] + h * (a1 * k1[i] + a2 * k2[i])
                    kout += 1
                t = tn
                y[:] = yn
                F0[:] = F2
                h *= min(5.0, max(0.2, 0.8 * err ** (-1 / 3))) if err > 0 else 5.0
                break
            h *= max(0.2, 0.8 * err ** (-1 / 3)) if math.isfinite(err) else 0.2
    return out, steps, nf


def main() -> None:
    t_end, dt = 0.5, 1e-4
    n = int(round(t_end / dt)) + 1
    cases = [("nominal, KP 1e5", {}, 1e5), ("Ct 5e-9, KP 1e5", {"Ct": 5e-9}, 1e5),
             ("nominal, KP 3.9e6", {}, 3.9e6), ("limit cycle: c1 1.25e5, KP 4e6", {"c1": 1.25e5}, 4e6)]
    print("| case | scheme | error / peak | steps | RHS evaluations | wall (ms) |")
    print("|---|---|---|---|---|---|")
    for label, kw, kp in cases:
        params, gains = MillParams(**kw), PIDGains(kp, 1e-3)
        ref = simulate(params, gains, t_end, method="reference", rtol=1e-10).x
        p, c, y0 = pack(params), drive_vector(gains), initial_state(params)
        atol = 1e-6 * state_scale(params)
        runs = [(f"RK4 h = {dt / m:.2g} s", lambda m=m: rk4(y0, p, c, dt, n, m)) for m in (4, 8, 16)]
        runs.append(("DP5(4) rtol 1e-6", lambda: dp54(y0, p, c, dt, n, 1e-6, atol, A, CN, E)))
        runs.append(("Rosenbrock ode23s rtol 1e-6", lambda: ros23(y0, p, c, dt, n, 1e-6, atol)))
        for name, fn in runs:
            fn()
            start = time.perf_counter()
            with np.errstate(all="ignore"):
                out, steps, nf = fn()
            wall = time.perf_counter() - start
            err = np.max(np.abs(out[:, 0] - ref)) / np.max(np.abs(ref))
            err = err if np.isfinite(err) and err < 1e3 else math.inf
            print(f"| {label} | {name} | {err:.1e} | {steps} | {nf} | {1e3 * wall:.2f} |")
        simulate(params, gains, t_end)
        run = simulate(params, gains, t_end)
        err = np.max(np.abs(run.x - ref)) / np.max(np.abs(ref))
        print(f"| {label} | **BS3(2) rtol 1e-6 (shipped)** | {err:.1e} | {run.n_steps} | ~{3 * run.n_steps} | "
              f"{1e3 * run.info['wall_s']:.2f} |")


if __name__ == "__main__":
    main()
