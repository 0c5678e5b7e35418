"""Microseconds per environment step where Python's bookkeeping weighs most: one Gymnasium environment (n = 1)
and the native VecEnv at 64, random actions in [-0.3, 0.3], the best of three runs; and a hash of everything the
steps return (observations, rewards, flags, infos), so two versions of the code can be held to the same steps.

    MILLVIB_NUM_THREADS=1 python scripts/step_overhead.py
    MILLVIB_NUM_THREADS=1 PYTHONPATH=<other checkout>/src python scripts/step_overhead.py   # the code before
"""
import hashlib
import json
import time

import gymnasium as gym
import numpy as np

import millvib_env  # noqa: F401 - registers the ids
from millvib_env.envs.vec_env import MillVibVecEnv


def h_update(h, obs, r, te, tr, info):
    h.update(np.ascontiguousarray(obs).tobytes())
    h.update(np.float64(r).tobytes())
    h.update(bytes([bool(te), bool(tr)]))
    h.update(json.dumps({k: v for k, v in info.items() if k != "signals"}, sort_keys=True, default=str).encode())


def single(env_id, kw, steps, seed=5):
    env = gym.make(env_id, **kw)
    rng = np.random.default_rng(0)
    h = hashlib.sha256()
    n, t = 0, 0.0
    obs, info = env.reset(seed=seed)
    while n < steps:
        a = rng.uniform(-0.3, 0.3, env.action_space.shape).astype(np.float32)
        t0 = time.perf_counter()
        out = env.step(a)
        t += time.perf_counter() - t0
        h_update(h, *out)
        n += 1
        if out[2] or out[3]:
            obs, info = env.reset()
    return t / n * 1e6, h.hexdigest()[:16]


def batched(env_id, kw, steps, n_envs=64):
    venv = MillVibVecEnv(env_id, n_envs, seed=3, **kw)
    rng = np.random.default_rng(1)
    venv.reset()
    h, t = hashlib.sha256(), 0.0
    for _ in range(steps):
        a = rng.uniform(-0.3, 0.3, (n_envs, venv.action_space.shape[0])).astype(np.float32)
        t0 = time.perf_counter()
        obs, r, d, infos = venv.step(a)
        t += time.perf_counter() - t0
        for arr in (obs, r, d):
            h.update(arr.tobytes())
        h.update(json.dumps([{k: v for k, v in i.items() if k != "terminal_observation"} for i in infos],
                            sort_keys=True, default=str).encode())
    return t / steps * 1e6, h.hexdigest()[:16]


CASES = [("Valve-v1 n=1", single, "MillVib-Valve-v1", dict(residual=True, config="rolling"), 3000),
         ("Gain-v1 n=1", single, "MillVib-GainSchedule-v1", dict(config="rolling"), 300),
         ("Valve-v0 n=1", single, "MillVib-Valve-v0", dict(), 1500),
         ("Valve-v1 n=64", batched, "MillVib-Valve-v1", dict(residual=True), 400)]


def main() -> None:
    for name, fn, eid, kw, steps in CASES:
        fn(eid, kw, 50)  # warm: compiled kernels loaded, first episode drawn
        best = None
        for _ in range(3):
            us, hx = fn(eid, kw, steps)
            best = us if best is None else min(best, us)
        print(f"{name:14s} {best:8.1f} us/step  steps' hash {hx}")


if __name__ == "__main__":
    main()
