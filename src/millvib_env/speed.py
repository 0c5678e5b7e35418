"""`millvib speed`: speed of the integrators and of environment stepping.

Plant timings, all on the 10 kHz output grid, integration only (the auxiliary outputs are
computed afterwards from the states, the same way for both methods):

* wall time per simulated second of one plant for LSODA at rtol 1e-6, driven from Python by scipy's
  `solve_ivp` and run whole in compiled code (the reference's default, `scipy.integrate.odeint`), and
  for the fast kernel, on the paper's nine cases, each the median of `repeats` runs;
* the fast kernel's trajectory error against the reference at tight tolerance (rtol 1e-10), as a
  fraction of the peak |x|;
* batched throughput: 256 plants drawn log-uniformly over c1, Ct and KP (the unstable corner
  included), in simulated plant-seconds per wall second, with all numba threads.
"""

from __future__ import annotations

import json
import math
import os
import platform
import statistics
import time
import warnings
from typing import Any, Callable

import numpy as np

from millvib_env._checks import integer, shown
from millvib_env._paths import write_text_atomic
from millvib_env.analysis.paper import PAPER_STUDIES
from millvib_env.params import MillParams, PIDGains, studied_range
from millvib_env.plant.integrate import simulate, simulate_batch
from millvib_env.threads import set_num_threads

__all__ = ["bench_plant", "bench_envs", "random_plants", "format_plant_bench", "format_env_bench"]


def random_plants(n: int, seed: int = 0, kp_range: tuple[float, float] = (1e4, 4e6)):
    """n plants and PID gains log-uniform over c1 in [1.25e5, 2.25e6], Ct in [5e-16, 5e-9], KP."""
    rng = np.random.default_rng(seed)
    c1_lo, c1_hi = np.log(studied_range("c1"))
    ct_lo, ct_hi = np.log(studied_range("Ct"))
    c1 = np.exp(rng.uniform(c1_lo, c1_hi, n))
    ct = np.exp(rng.uniform(ct_lo, ct_hi, n))
    kp = np.exp(rng.uniform(np.log(kp_range[0]), np.log(kp_range[1]), n))
    return [MillParams(c1=a, Ct=b) for a, b in zip(c1, ct)], [PIDGains(k, 1e-3) for k in kp]


def _median_wall(fn: Callable[[], float], repeats: int) -> float:
    return statistics.median(fn() for _ in range(repeats))


#: the limits of a plant benchmark's settings: the tight reference (rtol 1e-10) takes about a minute per
#: simulated second of the nine cases, so a longer or more repeated run is refused, not started
T_END_RANGE = (0.05, 5.0)
MAX_REPEATS = 50
#: plants in the batched-throughput row (`millvib speed --batch-size`)
BATCH_RANGE = (1, 4096)


def bench_plant(*, t_end: float = 1.0, repeats: int = 5, batch_size: int = 256, batch_t_end: float = 1.0,
                progress: bool = True) -> dict:
    lo, hi = T_END_RANGE
    if isinstance(t_end, bool) or not isinstance(t_end, (int, float)) or not lo <= t_end <= hi:
        raise ValueError(f"t_end = {shown(t_end)} s is invalid: a simulated time per case in [{lo}, {hi}] s")
    if isinstance(repeats, bool) or not isinstance(repeats, int) or not 1 <= repeats <= MAX_REPEATS:
        raise ValueError(f"repeats = {shown(repeats)} is invalid: a whole number in [1, {MAX_REPEATS}]")
    batch_size = integer("batch_size", batch_size, lo=BATCH_RANGE[0], hi=BATCH_RANGE[1])
    simulate(t_end=0.01)  # compile or load the kernels outside the timings
    simulate(t_end=0.01, method="reference")
    simulate(t_end=0.01, method="reference", ivp_method="LSODA")
    cases = [(c.label, c.params, c.gains) for s in PAPER_STUDIES for c in s.cases]
    iterator = cases
    if progress:
        from tqdm.auto import tqdm
        iterator = tqdm(cases, desc="bench: paper cases", unit="case")
    rows: list[dict[str, Any]] = []
    for label, params, gains in iterator:
        ref_s = _median_wall(lambda: simulate(params, gains, t_end, method="reference", rtol=1e-6,
                                              ivp_method="LSODA").info["wall_s"], repeats)
        odeint_s = _median_wall(lambda: simulate(params, gains, t_end, method="reference",
                                                 rtol=1e-6).info["wall_s"], repeats)
        fast_s = _median_wall(lambda: simulate(params, gains, t_end).info["wall_s"], repeats)
        tight = simulate(params, gains, t_end, method="reference", rtol=1e-10)
        fast = simulate(params, gains, t_end)
        err = float(np.max(np.abs(fast.x - tight.x)) / np.max(np.abs(tight.x)))
        rows.append({"case": label, "reference_s_per_sim_s": ref_s / t_end,
                     "compiled_reference_s_per_sim_s": odeint_s / t_end, "fast_s_per_sim_s": fast_s / t_end,
                     "speedup": ref_s / fast_s, "speedup_over_compiled": odeint_s / fast_s,
                     "fast_error_of_peak": err, "fast_steps": fast.n_steps})
    total_ref = sum(r["reference_s_per_sim_s"] for r in rows)
    total_fast = sum(r["fast_s_per_sim_s"] for r in rows)
    total_compiled = sum(r["compiled_reference_s_per_sim_s"] for r in rows)

    params, gains = random_plants(batch_size, seed=0)
    simulate_batch(params[:2], gains[:2], 0.01)
    start = time.perf_counter()
    batch = simulate_batch(params, gains, batch_t_end)
    wall = time.perf_counter() - start
    stable_params, stable_gains = random_plants(batch_size, seed=1, kp_range=(1e4, 3e5))
    start = time.perf_counter()
    simulate_batch(stable_params, stable_gains, batch_t_end)
    wall_stable = time.perf_counter() - start
    import numba

    return {
        "machine": {"processor": platform.processor() or platform.machine(), "python": platform.python_version(),
                    "numba_threads": numba.get_num_threads()},
        "t_end_s": t_end,
        "cases": rows,
        "aggregate_speedup": total_ref / total_fast,
        "aggregate_speedup_over_compiled": total_compiled / total_fast,
        "median_speedup": statistics.median(r["speedup"] for r in rows),
        "min_speedup": min(r["speedup"] for r in rows),
        "max_fast_error_of_peak": max(r["fast_error_of_peak"] for r in rows),
        "batch": {"plants": batch_size, "t_end_s": batch_t_end, "wall_s": wall,
                  "plant_seconds_per_wall_second": batch_size * batch_t_end / wall,
                  "diverged": int(batch.diverged.sum()),
                  "stable_draws_plant_seconds_per_wall_second": batch_size * batch_t_end / wall_stable},
    }


def format_plant_bench(res: dict) -> str:
    lines = [f"Integrators, wall time per simulated second of one plant (t_end = {res['t_end_s']} s, "
             f"10 kHz output, median of repeats):",
             "| case | solve_ivp LSODA rtol 1e-6 (ms) | compiled LSODA rtol 1e-6 (ms) | fast (ms) | "
             "speed-up over solve_ivp | over compiled | fast error / peak |",
             "|---|---|---|---|---|---|---|"]
    for r in res["cases"]:
        lines.append(f"| {r['case']} | {1e3 * r['reference_s_per_sim_s']:.2f} | "
                     f"{1e3 * r['compiled_reference_s_per_sim_s']:.2f} | {1e3 * r['fast_s_per_sim_s']:.3f} | "
                     f"{r['speedup']:.0f}x | {r['speedup_over_compiled']:.1f}x | {r['fast_error_of_peak']:.1e} |")
    lines.append(f"| **all nine (sum of times)** | | | | **{res['aggregate_speedup']:.0f}x** "
                 f"(median {res['median_speedup']:.0f}x, min {res['min_speedup']:.0f}x) | "
                 f"**{res['aggregate_speedup_over_compiled']:.1f}x** | max {res['max_fast_error_of_peak']:.1e} |")
    b = res["batch"]
    lines.append("")
    lines.append(f"Batched fast kernel, {b['plants']} plants x {b['t_end_s']} s, {res['machine']['numba_threads']} "
                 f"threads: {b['plant_seconds_per_wall_second']:.0f} plant-s per wall-s over random draws "
                 f"(KP 1e4-4e6, c1, Ct log-uniform; {b['diverged']} diverged), "
                 f"{b['stable_draws_plant_seconds_per_wall_second']:.0f} plant-s/s with KP <= 3e5 (no limit cycles).")
    return "\n".join(lines)


def _time_vec(venv, actions: np.ndarray) -> float:
    venv.reset()
    for a in actions[:5]:  # warm-up: kernels loaded, buffers touched
        venv.step(a)
    start = time.perf_counter()
    for a in actions[5:]:
        venv.step(a)
    return (len(actions) - 5) * venv.num_envs / (time.perf_counter() - start)


def bench_envs(*, n_envs: int = 64, native_steps: int = 1000, dummy_steps: int = 100, seed: int = 0,
               progress: bool = True) -> dict:
    """Environment steps per second: the native VecEnv against SB3's DummyVecEnv over single envs.

    Uniform random actions in [-1, 1] (the valve mode's full +-100 V range every millisecond: a
    hard, non-quiet load), new plants drawn at every reset, auto-resets included.
    """
    rows = []
    cases = [("MillVib-Valve-v0", {}), ("MillVib-Valve-v0", {"residual": True}), ("MillVib-GainSchedule-v0", {})]
    iterator = cases
    if progress:
        from tqdm.auto import tqdm
        iterator = tqdm(cases, desc="bench: environments", unit="env")
    for env_id, kwargs in iterator:
        with warnings.catch_warnings():  # Gymnasium's note that a v1 exists: the v0 engine is timed on purpose
            warnings.filterwarnings("ignore", message=".*is out of date.*")
            rows.append(_bench_env(env_id, kwargs, n_envs, native_steps, dummy_steps, seed))
    return {"n_envs": n_envs, "rows": rows, **machine_state()}


def _bench_env(env_id: str, kwargs: dict, n_envs: int, native_steps: int, dummy_steps: int, seed: int) -> dict:
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv

    from millvib_env.envs.vec_env import MillVibVecEnv

    native = MillVibVecEnv(env_id, n_envs, seed=seed, **kwargs)
    rng = np.random.default_rng(seed)
    act_shape: tuple[int, ...] = native.action_space.shape  # type: ignore[assignment]  # a Box's is set
    acts = rng.uniform(-1, 1, (native_steps + 5, n_envs, *act_shape)).astype(np.float32)
    native_rate = _time_vec(native, acts)
    set_num_threads(1)  # the same batch on one thread: what threads give on this machine now
    try:
        serial_native = MillVibVecEnv(env_id, n_envs, seed=seed, **kwargs)
        serial_rate = _time_vec(serial_native, acts)
    finally:
        set_num_threads(None)
    dummy = DummyVecEnv([lambda: gym.make(env_id, **kwargs) for _ in range(n_envs)])
    dummy.seed(seed)
    dummy_rate = _time_vec(dummy, acts[:dummy_steps + 5])
    return {"env_id": env_id + (" (residual)" if kwargs.get("residual") else ""), "n_envs": n_envs,
            "native_steps_per_s": native_rate, "serial_steps_per_s": serial_rate, "dummy_steps_per_s": dummy_rate,
            "speedup": native_rate / dummy_rate, "simulated_s_per_wall_s": native_rate * native.core.settings.period_s}


def machine_state() -> dict:
    """What the figures were measured under: the load average, the cores, the threads' wait policy."""
    import numba

    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    return {"load_1min": round(load[0], 2), "cpus": os.cpu_count(), "plant_threads": numba.config.NUMBA_NUM_THREADS,  # type: ignore[attr-defined]
            "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", "")}


def format_env_bench(res: dict) -> str:
    lines = [f"Environment stepping, {res['n_envs']} envs, uniform random actions, auto-resets included "
             f"(load {res.get('load_1min', math.nan):g} on {res.get('cpus')} CPUs, {res.get('plant_threads')} plant "
             f"threads, OMP_WAIT_POLICY={res.get('omp_wait_policy') or 'unset'}):",
             "| environment | native VecEnv (steps/s) | the same, one thread | SB3 DummyVecEnv (steps/s) | speed-up | "
             "simulated s per wall s |",
             "|---|---|---|---|---|---|"]
    for r in res["rows"]:
        serial = f"{r['serial_steps_per_s']:,.0f}" if "serial_steps_per_s" in r else "-"
        lines.append(f"| {r['env_id']} | {r['native_steps_per_s']:,.0f} | {serial} | {r['dummy_steps_per_s']:,.0f} | "
                     f"{r['speedup']:.1f}x | {r['simulated_s_per_wall_s']:.0f} |")
    return "\n".join(lines)


def save_json(res: dict, path: str) -> None:
    write_text_atomic(path, json.dumps(res, indent=2))
