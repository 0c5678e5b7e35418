"""Offline PID tuning for the baselines: grid search over log gains, then Nelder-Mead.

The objective is the benchmark's mean episode cost (severity / 4.5 mm/s + tracking RMS / 10 um)
over a fixed set of training plants (episode seeds in TUNING_SEEDS, disjoint from the benchmark's
held-out seeds), in the gain-schedule environment with the gains held fixed. Many gain sets are
evaluated in one batch: environment j runs gain set j // M on plant j % M.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import optimize

from millvib_env.control.policies import Controller, gains_to_action
from millvib_env.envs.config import load_env_config
from millvib_env.envs.core import log_gain_bounds
from millvib_env.training.evaluate import run_episodes

__all__ = ["TUNING_SEEDS", "GRID", "TuneResult", "mean_costs", "tune", "ActionTable"]

#: episode seeds used for tuning the baselines (the benchmark uses 20000 and up, training < 10000)
TUNING_SEEDS = range(10_000, 11_000)

#: the coarse grid (log10 of KP, KI, KD) the search starts from
GRID = (np.arange(4.0, 7.01, 0.25), np.array([-3.0, 2.0, 4.0, 5.0, 6.0, 7.0, 8.0]),
        np.array([0.0, 1.0, 1.5, 2.0, np.log10(300.0)]))


class ActionTable(Controller):
    """A fixed action per environment (a batch of fixed-gain PIDs)."""

    name = "gain-table"

    def __init__(self, actions: np.ndarray):
        self.actions = np.asarray(actions, dtype=np.float32)

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return self.actions, state


def mean_costs(log_gain_sets: np.ndarray, seeds: Sequence[int], *, params: dict | None = None,
               chunk: int = 4096) -> np.ndarray:
    """Mean episode cost of each gain set (rows of log10 KP, KI, KD) over the plants `seeds`.

    `params` pins plant parameters (e.g. the nominal plant); otherwise each seed draws its plant.
    Diverged episodes count with their (large) cost; a non-finite cost counts as 1e6.
    """
    cfg = load_env_config("default")
    sets = np.atleast_2d(np.asarray(log_gain_sets, float))
    m = len(seeds)
    costs = np.empty((sets.shape[0], m))
    actions = gains_to_action(10.0 ** sets, cfg)
    per_chunk = max(1, chunk // m)
    for start in range(0, sets.shape[0], per_chunk):
        block = actions[start:start + per_chunk]
        table = ActionTable(np.repeat(block, m, axis=0))
        recs = _run(table, list(seeds) * block.shape[0], params)
        c = np.array([r["cost"] if math.isfinite(r["cost"]) else 1e6 for r in recs]).reshape(block.shape[0], m)
        costs[start:start + block.shape[0]] = c
    return costs.mean(axis=1)


def _run(table: ActionTable, seeds: list[int], params: dict | None) -> list[dict]:
    if params:
        # pin the plant: the randomised parameters are replaced by fixed ones
        randomize = {k: {"dist": "fixed", "low": v} for k, v in params.items()}
        return run_episodes(table, seeds, env_kwargs={"randomize": randomize})
    return run_episodes(table, seeds)


@dataclass
class TuneResult:
    log10_gains: np.ndarray
    cost: float
    grid_best: np.ndarray
    grid_cost: float
    n_evaluations: int

    @property
    def gains(self) -> list[float]:
        return [float(g) for g in 10.0 ** self.log10_gains]


def tune(seeds: Sequence[int], *, params: dict | None = None, grid=GRID, refine_iters: int = 60) -> TuneResult:
    """Grid search over `grid`, then Nelder-Mead from the best point, on the plants `seeds`."""
    lo, hi = log_gain_bounds(load_env_config("default"))
    mesh = np.stack(np.meshgrid(*grid, indexing="ij"), axis=-1).reshape(-1, 3)
    mesh = np.clip(mesh, lo, hi)
    grid_costs = mean_costs(mesh, seeds, params=params)
    best = mesh[int(np.argmin(grid_costs))]
    n_eval = len(mesh)

    def objective(u: np.ndarray) -> float:
        nonlocal n_eval
        n_eval += 1
        return float(mean_costs(np.clip(u, lo, hi)[None, :], seeds, params=params)[0])

    res = optimize.minimize(objective, best, method="Nelder-Mead",
                            options={"maxiter": refine_iters, "xatol": 0.02, "fatol": 1e-3,
                                     "initial_simplex": best + np.vstack([np.zeros(3), 0.15 * np.eye(3)])})
    final = np.clip(res.x, lo, hi)
    final_cost = float(res.fun)
    if final_cost > grid_costs.min():
        final, final_cost = best, float(grid_costs.min())
    return TuneResult(final, final_cost, best, float(grid_costs.min()), n_eval)
