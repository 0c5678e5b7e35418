"""Offline PID tuning for the baselines: grid search over log gains, then Nelder-Mead.

A grid of 50 gain sets or more is raced (`raced_costs`): every set on a quarter of the plants, the cheapest third
of them on all the plants. On every grid `millvib tune` searches on the four tasks (measured: docs/performance.md)
the race kept the whole grid's cheapest set, so the search ends where the whole grid's would, at about half of the
grid's episodes.

The objective is the benchmark's mean episode cost (severity / 4.5 mm/s + tracking RMS / 10 um)
over a fixed set of plants (the task's tuning seeds, disjoint from its held-out seeds), in the
gain-schedule environment of the task with the gains held fixed. Many gain sets are evaluated in
one batch: environment j runs gain set j // M on plant j % M.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from scipy import optimize

from millvib_env._checks import shown
from millvib_env.control.adaptive import AdaptivePolicy, EstimatorSettings
from millvib_env.control.base import Controller
from millvib_env.catalog.factory import oracle_table
from millvib_env.control.lqr import LQRWeights, lqr_gains
from millvib_env.control.policies import LQRPolicy
from millvib_env.catalog.named import named_gains
from millvib_env.control.preview import FF_CHANNELS, PreviewFeedforward
from millvib_env.catalog.registry import REFERENCE
from millvib_env.distributed import run_jobs
from millvib_env.envs.actions import WIDE_BOUNDS, GainMap, wide_actions
from millvib_env.envs.batch import EpisodeBatch, env_id_for
from millvib_env.envs.config import load_env_config
from millvib_env.tasks import Task
from millvib_env.evaluation.evaluate import run_episodes
from millvib_env.envs.config import DEFAULT_VERSION

__all__ = ["GRID", "PF_BOUNDS", "TuneResult", "mean_costs", "episode_costs", "raced_costs", "tune", "tune_from",
           "gain_env_kwargs", "ActionTable",
           "preview_costs", "tune_preview", "tune_preview_per_plant", "PREVIEW_TUNING_GAUGE"]

#: the coarse grid (log10 of KP, KI, KD) the search starts from
GRID = (np.arange(4.0, 7.01, 0.25), np.array([-3.0, 2.0, 4.0, 5.0, 6.0, 7.0, 8.0]),
        np.array([0.0, 1.0, 1.5, 2.0, np.log10(300.0)]))


class ActionTable(Controller):
    """A fixed action per environment (a batch of fixed-gain PIDs)."""

    name = "gain-table"

    def __init__(self, actions: np.ndarray, env_kwargs: dict | None = None, version: str = DEFAULT_VERSION):
        self.actions = np.asarray(actions, dtype=np.float32)
        self.env_kwargs = dict(env_kwargs or {})
        self.env_id = env_id_for("gain", version)

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return self.actions, state


#: the search bounds (V/m, V/(m s), V s/m, V/Pa, V/N) of the tunings with pressure feedback (and force
#: feedforward)
PF_BOUNDS = WIDE_BOUNDS


def gain_env_kwargs(task: Task, n_gains: int, params: dict | None = None) -> dict:
    """The gain-schedule env a tuning runs fixed gain sets of `n_gains` entries in: 3 = PID (the
    task's own action bounds), 4 = + pressure feedback, 5 = + force feedforward (`PF_BOUNDS`).
    `params` pins plant parameters (e.g. the nominal plant)."""
    env_kwargs: dict = {"config": task.config}
    if n_gains != 3:
        env_kwargs["actions"] = wide_actions(n_gains)
    if params:  # pin the plant: the randomised parameters are replaced by fixed ones
        env_kwargs["randomize"] = {k: {"dist": "fixed", "low": v} for k, v in params.items()}
    return env_kwargs


def mean_costs(log_gain_sets: np.ndarray, seeds: Sequence[int], *, task: Task,
               params: dict | None = None, chunk: int = 4096, version: str = DEFAULT_VERSION) -> np.ndarray:
    """Mean episode cost of each gain set (rows of log10 KP, KI, KD[, KPL[, KFF]]) over the plants `seeds`,
    in environment version `version`.

    `params` pins plant parameters (e.g. the nominal plant); otherwise each seed draws its plant.
    Diverged episodes count with their scored cost (at least `DIVERGED_COST`: `evaluate.scored_cost`);
    a non-finite cost counts as 1e6.
    """
    return episode_costs(log_gain_sets, seeds, task=task, params=params, chunk=chunk, version=version).mean(axis=1)


def episode_costs(log_gain_sets: np.ndarray, seeds: Sequence[int], *, task: Task,
                  params: dict | None = None, chunk: int = 4096, version: str = DEFAULT_VERSION) -> np.ndarray:
    """`mean_costs`' episodes: the cost of gain set i on plant seeds[j] at [i, j]. An episode's cost is its own, the
    same in any batch (each environment of the batch runs alone through the compiled kernel)."""
    sets = np.atleast_2d(np.asarray(log_gain_sets, float))
    env_kwargs = gain_env_kwargs(task, sets.shape[1], params)
    gain_map = GainMap.from_config(load_env_config(**env_kwargs, version=version))
    m = len(seeds)
    costs = np.empty((sets.shape[0], m))
    actions = gain_map.action(10.0 ** sets)
    per_chunk = max(1, chunk // m)
    for start in range(0, sets.shape[0], per_chunk):
        block = actions[start:start + per_chunk]
        table = ActionTable(np.repeat(block, m, axis=0), env_kwargs, version)
        recs = run_episodes(table, list(seeds) * block.shape[0])
        c = np.array([r["cost"] if math.isfinite(r["cost"]) else 1e6 for r in recs]).reshape(block.shape[0], m)
        costs[start:start + block.shape[0]] = c
    return costs


#: racing a search's starting grid (`raced_costs`): at least this many gain sets and this many plants, the share of
#: the plants every set is scored on first, and the share of the sets (at least `RACE_KEEP_MIN`) scored on the rest
RACE_MIN_SETS, RACE_MIN_PLANTS, RACE_FIRST, RACE_KEEP, RACE_KEEP_MIN = 50, 4, 0.25, 1 / 3, 10


def raced_costs(log_gain_sets: np.ndarray, seeds: Sequence[int], *, task: Task, params: dict | None = None,
                version: str = DEFAULT_VERSION) -> np.ndarray:
    """The mean cost over `seeds` of the gain sets a race keeps, inf for the others: every set is scored on the first
    quarter of the plants (`RACE_FIRST`, at least 2), and the cheapest third of the sets there (`RACE_KEEP`, at least
    `RACE_KEEP_MIN`) on the rest too (successive halving in one round, as Hyperband's brackets race configurations on
    a small budget first). A kept set's mean is `mean_costs`' number to the bit: the same episodes, averaged in the
    plants' order. A small grid, or few plants, is scored whole."""
    sets = np.atleast_2d(np.asarray(log_gain_sets, float))
    m = len(seeds)
    if sets.shape[0] < RACE_MIN_SETS or m < RACE_MIN_PLANTS:
        return mean_costs(sets, seeds, task=task, params=params, version=version)
    first = max(2, int(RACE_FIRST * m))
    head = episode_costs(sets, seeds[:first], task=task, params=params, version=version)
    keep = np.sort(np.argsort(head.mean(axis=1), kind="stable")[:max(RACE_KEEP_MIN, math.ceil(RACE_KEEP * len(sets)))])
    rest = episode_costs(sets[keep], seeds[first:], task=task, params=params, version=version)
    out = np.full(len(sets), np.inf)
    out[keep] = np.concatenate([head[keep], rest], axis=1).mean(axis=1)
    return out


def tune_from(starts: np.ndarray, seeds: Sequence[int], *, task: Task, params: dict | None = None,
              refine_iters: int = 150, step_decades: float = 0.3, version: str = DEFAULT_VERSION,
              progress: str | None = None) -> "TuneResult":
    """The best of several starting gain sets (rows of log10 gains, 4 or 5 wide), refined by
    Nelder-Mead within `PF_BOUNDS` on the plants `seeds`."""
    starts = np.atleast_2d(np.asarray(starts, float))
    names = ("kp", "ki", "kd", "kpl", "kff")[:starts.shape[1]]
    lo = np.log10([PF_BOUNDS[k][0] for k in names])
    hi = np.log10([PF_BOUNDS[k][1] for k in names])
    return _refine(starts, lo, hi, seeds, task=task, params=params, refine_iters=refine_iters, step=step_decades,
                   xatol=0.01, fatol=1e-4, bounded=True, version=version, progress=progress)


def _refine(starts: np.ndarray, lo: np.ndarray, hi: np.ndarray, seeds: Sequence[int], *, task: Task,
            params: dict | None, refine_iters: int, step: float, xatol: float, fatol: float,
            bounded: bool, version: str = DEFAULT_VERSION, progress: str | None = None) -> "TuneResult":
    """The cheapest of `starts` (rows of log10 gains, clipped to [lo, hi]) on the plants `seeds`, refined
    by Nelder-Mead; never worse than that start. `bounded`: Nelder-Mead within [lo, hi], its first
    simplex stepping inwards from a bound (KD at 300); otherwise the objective clips the gains.
    `progress`: a bar of that name counting the evaluations, with the best mean cost so far."""
    from tqdm.auto import tqdm

    bar = tqdm(desc=progress, unit="eval", disable=progress is None, leave=False)
    with bar:
        return _refine_in(starts, lo, hi, seeds, task=task, params=params, refine_iters=refine_iters, step=step,
                          xatol=xatol, fatol=fatol, bounded=bounded, version=version, bar=bar)


def _refine_in(starts, lo, hi, seeds, *, task, params, refine_iters, step, xatol, fatol, bounded, version,
               bar) -> "TuneResult":
    starts = np.clip(starts, lo, hi)
    start_costs = raced_costs(starts, seeds, task=task, params=params, version=version)
    best = starts[int(np.argmin(start_costs))]
    n_eval = len(starts)
    bar.update(n_eval)
    lowest = [float(start_costs.min())]
    bar.set_postfix(best=f"{lowest[0]:.4f}")

    def objective(u: np.ndarray) -> float:
        nonlocal n_eval
        n_eval += 1
        cost = float(mean_costs(np.clip(u, lo, hi)[None, :], seeds, task=task, params=params, version=version)[0])
        bar.update(1)
        if cost < lowest[0]:
            lowest[0] = cost
            bar.set_postfix(best=f"{cost:.4f}")
        return cost

    dim = len(best)
    simplex = best + np.vstack([np.zeros(dim), step * np.eye(dim)])
    extra = {}
    if bounded:
        simplex = np.where(simplex > hi, 2 * best - simplex, simplex)
        extra["bounds"] = list(zip(lo, hi))
    res = optimize.minimize(objective, best, method="Nelder-Mead", **extra,
                            options={"maxiter": refine_iters, "xatol": xatol, "fatol": fatol,
                                     "initial_simplex": simplex})
    final, final_cost = np.clip(res.x, lo, hi), float(res.fun)
    if final_cost > start_costs.min():
        final, final_cost = best, float(start_costs.min())
    return TuneResult(final, final_cost, best, float(start_costs.min()), n_eval)


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


def tune(seeds: Sequence[int], *, task: Task, params: dict | None = None, grid=GRID,
         refine_iters: int = 60, version: str = DEFAULT_VERSION, progress: str | None = None) -> TuneResult:
    """Grid search over `grid` (raced: `raced_costs`), then Nelder-Mead from the best point, on the plants `seeds`."""
    gain_map = GainMap.from_config(task.configs["v0"])
    lo, hi = gain_map.log_lo, gain_map.log_hi
    mesh = np.stack(np.meshgrid(*grid, indexing="ij"), axis=-1).reshape(-1, 3)
    return _refine(mesh, lo, hi, seeds, task=task, params=params, refine_iters=refine_iters, step=0.15,
                   xatol=0.02, fatol=1e-3, bounded=False, version=version, progress=progress)


def plants_of(seeds: Sequence[int], task: Task, version: str = DEFAULT_VERSION) -> list:
    """The plants (MillParams) the task's environment draws for episode seeds `seeds`."""

    batch = EpisodeBatch(env_id_for("gain", version), len(seeds), config=task.config)
    batch.reset(seeds)
    return list(batch.core.params)


def lqr_costs(weight_sets: Sequence, seeds: Sequence[int], *, task: Task, chunk: int = 4096,
              version: str = DEFAULT_VERSION) -> np.ndarray:
    """Mean episode cost of the LQR reference with each of `weight_sets` (LQRWeights) over `seeds`.

    Each plant's gains are designed for its true c1 and Ct, as `lqr-oracle` does; a design that
    fails (no stabilising solution) costs 1e6.
    """

    env_kwargs: dict[str, Any] = {"config": task.config, **LQRPolicy.ENV_KWARGS}
    cfg = load_env_config(**env_kwargs, version=version)
    gain_map = GainMap.from_config(cfg)
    dt_s = None if cfg.loop is None else cfg.loop.dt_s
    plants = plants_of(seeds, task, version)
    m = len(seeds)
    rows, designed = [], []
    for w in weight_sets:
        for p in plants:
            try:
                g = lqr_gains(p, w, dt_s=dt_s)
                designed.append(bool(np.all(np.isfinite(g))))
            except (np.linalg.LinAlgError, ValueError):
                g = np.zeros(4)
                designed.append(False)
            rows.append(gain_map.action(np.nan_to_num(g)))
    actions = np.array(rows)
    ok = np.array(designed).reshape(len(weight_sets), m)
    costs = np.empty((len(weight_sets), m))
    per_chunk = max(1, chunk // m)
    for start in range(0, len(weight_sets), per_chunk):
        block = actions[start * m:(start + per_chunk) * m]
        k = len(block) // m
        recs = run_episodes(ActionTable(block, env_kwargs, version), list(seeds) * k)
        costs[start:start + k] = np.array([r["cost"] if math.isfinite(r["cost"]) else 1e6 for r in recs]).reshape(k, m)
    costs[~ok] = 1e6
    return costs.mean(axis=1)


LQR_GRID = {"q_v": (1e-4, 1e-3, 1e-2, 1e-1), "q_p": (1e-4, 1e-2, 1.0), "q_i": (1e-4, 1e-2, 1.0, 100.0),
            "r": (0.1, 1.0, 10.0, 100.0), "friction": ("stick", "sliding")}


def tune_lqr(seeds: Sequence[int], *, task: Task, refine_iters: int = 40, version: str = DEFAULT_VERSION) -> dict:
    """Grid over `LQR_GRID`, then Nelder-Mead in log10 (q_v, q_p, q_i, r) with the best friction."""

    keys = ("q_v", "q_p", "q_i", "r")
    grid = [dict(zip(keys + ("friction",), combo)) for combo in np.stack(np.meshgrid(
        *[np.arange(len(LQR_GRID[k])) for k in keys + ("friction",)], indexing="ij"), -1).reshape(-1, 5)]
    sets = [LQRWeights(**{k: LQR_GRID[k][int(c[k])] for k in keys + ("friction",)})  # type: ignore[arg-type]
            for c in grid]
    costs = lqr_costs(sets, seeds, task=task, version=version)
    best = sets[int(np.argmin(costs))]
    n_eval = len(sets)

    def objective(u: np.ndarray) -> float:
        nonlocal n_eval
        n_eval += 1
        return float(lqr_costs([LQRWeights(**dict(zip(keys, 10.0 ** u)), friction=best.friction)], seeds,
                               task=task, version=version)[0])

    x0 = np.log10([getattr(best, k) for k in keys])
    res = optimize.minimize(objective, x0, method="Nelder-Mead",
                            options={"maxiter": refine_iters, "xatol": 0.05, "fatol": 1e-3,
                                     "initial_simplex": x0 + np.vstack([np.zeros(4), 0.5 * np.eye(4)])})
    if res.fun < costs.min():
        weights = {**dict(zip(keys, [float(v) for v in 10.0 ** res.x])), "friction": best.friction}
        cost = float(res.fun)
    else:
        weights = {k: getattr(best, k) for k in keys + ("friction",)}
        cost = float(costs.min())
    weights = {"q_x": 1.0, **{k: (round(v, 6 - int(math.floor(math.log10(abs(v))))) if isinstance(v, float) else v)
                              for k, v in weights.items()}}
    return {"weights": weights, "tuning_cost": round(cost, 4), "grid_cost": round(float(costs.min()), 4),
            "n_evaluations": n_eval}


ADAPTIVE_TAUS = (0.05, 0.1, 0.2, 0.5, 1.0)


def tune_adaptive(seeds: Sequence[int], *, task: Task, taus: Sequence[float] = ADAPTIVE_TAUS, table=None,
                  version: str = DEFAULT_VERSION) -> dict:
    """The estimator's forgetting time constant with the lowest mean cost on `seeds` (gains from
    `table`, default the task's shipped pid-oracle table)."""
    cfg = task.configs[version]
    table, gain_map = (oracle_table(task, version=version) if table is None else table), GainMap.from_config(cfg)
    costs: dict[float, float] = {}
    for tau in taus:
        ctrl = AdaptivePolicy(table, gain_map, EstimatorSettings(tau_s=tau), cfg.base_params,
                              sample_rate_hz=cfg.sample_rate_hz)
        ctrl.env_id = env_id_for("gain", version)
        recs = run_episodes(ctrl, list(seeds), task=task)
        costs[tau] = float(np.mean([r["cost"] if math.isfinite(r["cost"]) else 1e6 for r in recs]))
    tau = min(costs, key=lambda t: costs[t])
    return {"estimator": {"tau_s": tau, "highpass_hz": EstimatorSettings().highpass_hz,
                          "min_info": EstimatorSettings().min_info},
            "tuning_costs": {str(k): round(v, 4) for k, v in costs.items()}}


def optuna_storage(storage: str):
    """An Optuna storage from a CLI string: ``journal:PATH`` (a journal file several machines can share
    on a common file system) or a database URL (``sqlite:///tune.db``, ``postgresql://...``)."""
    import optuna

    if not isinstance(storage, str) or not (storage.startswith("journal:") or "://" in storage):
        raise ValueError(f"--optuna {shown(storage)} is invalid: journal:PATH or a database URL such as sqlite:///tune.db")
    try:
        if storage.startswith("journal:"):
            from optuna.storages.journal import JournalFileBackend, JournalStorage

            return JournalStorage(JournalFileBackend(storage[len("journal:"):]))
        return optuna.storages.RDBStorage(storage)
    except Exception as err:  # an unknown dialect, a driver not installed, a file that cannot be opened
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise ValueError(f"--optuna {shown(storage)} cannot be opened: {first[:200]}") from None


def tune_optuna(seeds: Sequence[int], *, task: Task, storage: str, study_name: str, n_trials: int,
                params: dict | None = None, sampler_seed: int | None = None, version: str = DEFAULT_VERSION) -> dict:
    """PID gains by an Optuna study (TPE) over log10 KP, KI, KD in the action bounds, minimising the
    mean cost on `seeds`; several processes or machines running this with the same storage and
    study name share the study. Returns the study's best gains so far."""
    import optuna

    gain_map = GainMap.from_config(task.configs["v0"])
    lo, hi = gain_map.log_lo, gain_map.log_hi
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(study_name=study_name, storage=optuna_storage(storage), direction="minimize",
                                load_if_exists=True, sampler=optuna.samplers.TPESampler(seed=sampler_seed))

    def objective(trial) -> float:
        u = np.array([trial.suggest_float(name, lo[k], hi[k]) for k, name in enumerate(("log10_kp", "log10_ki",
                                                                                       "log10_kd"))])
        return float(mean_costs(u[None, :], seeds, task=task, params=params, version=version)[0])

    study.optimize(objective, n_trials=n_trials)
    best = np.array([study.best_params[k] for k in ("log10_kp", "log10_ki", "log10_kd")])
    return {"gains": [float(g) for g in 10.0 ** best], "log10_gains": [round(float(v), 4) for v in best],
            "tuning_cost": round(float(study.best_value), 4), "n_trials": len(study.trials)}


#: the measured preview's setting the preview feedforward is tuned with (`envs.gauge`): the benchmark's default
PREVIEW_TUNING_GAUGE = "measured"


def preview_costs(gain_sets: np.ndarray, seeds: Sequence[int], *, task: Task, gauge: str | dict = PREVIEW_TUNING_GAUGE,
                  chunk: int = 1200) -> np.ndarray:
    """Mean episode cost of each row of preview-feedforward gains (`control.preview.FF_CHANNELS`, in the tuner's
    units) over the plants `seeds`, with the preview `gauge` (exact or measured), in one batch per `chunk`
    environments: environment j runs gain set j // M on plant j % M (each row's numbers as alone)."""
    sets = np.atleast_2d(np.asarray(gain_sets, float))
    m = len(seeds)
    costs = np.empty((sets.shape[0], m))
    per_chunk = max(1, chunk // m)
    for start in range(0, sets.shape[0], per_chunk):
        block = sets[start:start + per_chunk]
        ctrl = PreviewFeedforward("preview-table", np.repeat(block, m, axis=0), named_gains(REFERENCE, task, "v1"))
        ctrl.task = task
        recs = run_episodes(ctrl, list(seeds) * block.shape[0], task=task,
                            env_kwargs={"observation": {"preview_gauge": gauge}})
        c = np.array([r["cost"] if math.isfinite(r["cost"]) else 1e6 for r in recs]).reshape(block.shape[0], m)
        costs[start:start + block.shape[0]] = c
    return costs.mean(axis=1)


def _preview_costs_in(processes: int, gain_sets: np.ndarray, seeds: Sequence[int], task: Task,
                      gauge: str | dict) -> np.ndarray:
    """`preview_costs` of the rows of `gain_sets`, split into `processes` runs of consecutive rows in worker processes
    (one process: here)."""
    if processes <= 1:
        return preview_costs(gain_sets, seeds, task=task, gauge=gauge)
    parts = np.array_split(np.atleast_2d(gain_sets), min(processes, len(gain_sets)))
    jobs = [{"gain_sets": part, "seeds": list(seeds), "task": task, "gauge": gauge} for part in parts]
    return np.concatenate(run_jobs(preview_costs, jobs, processes=processes))


def _pair_costs(gains: np.ndarray, seeds: Sequence[int], task: Task, gauge: str | dict, chunk: int,
                params: Sequence[dict | None] | None = None) -> np.ndarray:
    """Episode cost of environment j: gain row j on plant seeds[j] (with the plant parameters params[j] where
    given), `chunk` environments a batch (each row's number as alone: `PreviewFeedforward.batch_exact`)."""
    out = np.empty(len(seeds))
    params = [None] * len(seeds) if params is None else list(params)
    for a in range(0, len(seeds), chunk):
        ctrl = PreviewFeedforward("preview-table", gains[a:a + chunk], named_gains(REFERENCE, task, "v1"))
        ctrl.task = task
        recs = run_episodes(ctrl, list(seeds[a:a + chunk]), task=task, params=params[a:a + chunk],
                            env_kwargs={"observation": {"preview_gauge": gauge}})
        out[a:a + chunk] = [r["cost"] if math.isfinite(r["cost"]) else 1e6 for r in recs]
    return out


class _Lockstep:
    """Searches that run in threads and only wait: each `ask`s for its points' costs, and the caller's thread
    (`serve`) evaluates every waiting search's points in one batch with `evaluate(points per search)`."""

    def __init__(self, n: int, evaluate):
        import threading

        self.cond = threading.Condition()
        self.evaluate = evaluate
        self.asked: dict[int, np.ndarray] = {}
        self.answered: dict[int, np.ndarray] = {}
        self.running = n
        self.failed: list[BaseException] = []

    def ask(self, i: int, points: np.ndarray) -> np.ndarray:
        with self.cond:
            self.asked[i] = points
            self.cond.notify_all()
            while i not in self.answered:
                self.cond.wait()
            return self.answered.pop(i)

    def finished(self, exc: BaseException | None = None) -> None:
        with self.cond:
            self.running -= 1
            if exc is not None:
                self.failed.append(exc)
            self.cond.notify_all()

    def serve(self, bar) -> None:
        while True:
            with self.cond:
                while len(self.asked) < self.running and not self.failed:
                    self.cond.wait()
                if self.failed:
                    raise self.failed[0]
                if self.running == 0:
                    return
                batch = dict(self.asked)
                self.asked.clear()
            costs = self.evaluate(batch)
            with self.cond:
                self.answered.update(costs)
                self.cond.notify_all()
            bar.update(1)
            bar.set_postfix(searches=len(batch))


def tune_preview_per_plant(seeds: Sequence[int], *, task: Task, start: Sequence[float],
                           gauge: str | dict = PREVIEW_TUNING_GAUGE, iters: int = 30, fd_step: float = 0.02,
                           bound: float = 100.0, chunk: int = 1200, progress: str | None = None,
                           episodes: Sequence[Sequence[int]] | None = None,
                           params: Sequence[dict | None] | None = None) -> dict:
    """The preview feedforward's gains re-tuned for each plant: per plant, `tune_preview`'s search (L-BFGS-B within
    +-`bound`, forward differences of `fd_step`) from `start` (the shipped gains), with the preview `gauge`, on the
    mean cost of its `episodes` (seeds; default: the plant's own episode, seeds[i] alone) with its plant parameters
    `params[i]` pinned (the reset option; default: each episode's own draw). On its own episode it approaches the
    most any schedule of the 17 gains could reach, an adaptive one included: it knows the plant and the very
    disturbances it is scored on (a local search: the cost is not convex once the valve saturates). On other
    episodes of the same plant it is the gains an ideal adaptive controller would schedule: the plant known, its
    disturbances not. The plants' searches run in lockstep (one thread each, which only waits:
    `_Lockstep`), so each round's points of every plant go through the compiled kernel in one batch; each plant's
    numbers are those of its search alone. Returns per plant the best gains, their cost and the cost at `start`
    (means over its episodes)."""
    import threading

    from tqdm.auto import tqdm

    seeds = [int(s) for s in seeds]
    x0 = np.asarray(start, float)
    dim = len(FF_CHANNELS)
    if x0.shape != (dim,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"start = {shown(start)} is invalid: {dim} finite gains ({', '.join(FF_CHANNELS)})")
    runs = [[s] for s in seeds] if episodes is None else [[int(e) for e in es] for es in episodes]
    pins = [None] * len(seeds) if params is None else list(params)
    if len(runs) != len(seeds) or len(pins) != len(seeds) or not all(runs):
        raise ValueError(f"episodes and params are invalid: one non-empty list of seeds and one dict (or None) for "
                         f"each of the {len(seeds)} plants")
    best: list[tuple[float, np.ndarray]] = [(math.inf, x0)] * len(seeds)
    first = [math.nan] * len(seeds)

    def evaluate(batch: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
        order = sorted(batch)
        rows = np.vstack([np.repeat(batch[i], len(runs[i]), axis=0) for i in order])
        env_seeds = [e for i in order for _ in range(dim + 1) for e in runs[i]]
        env_params = [pins[i] for i in order for _ in range(dim + 1) for _ in runs[i]]
        c = _pair_costs(rows, env_seeds, task, gauge, chunk, env_params)
        out, at = {}, 0
        for i in order:
            k = len(runs[i])
            out[i] = c[at:at + (dim + 1) * k].reshape(dim + 1, k).mean(axis=1)
            at += (dim + 1) * k
        return out

    step = _Lockstep(len(seeds), evaluate)

    def search(i: int) -> None:
        def cost_and_grad(x: np.ndarray) -> tuple[float, np.ndarray]:
            c = step.ask(i, np.vstack([x, x + fd_step * np.eye(dim)]))
            first[i] = float(c[0]) if math.isnan(first[i]) else first[i]
            best[i] = min(best[i], (float(c[0]), x.copy()), key=lambda b: b[0])
            return float(c[0]), (c[1:] - c[0]) / fd_step

        try:
            optimize.minimize(cost_and_grad, x0, jac=True, method="L-BFGS-B", bounds=[(-bound, bound)] * dim,
                              options={"maxiter": iters, "ftol": 1e-5})
        except BaseException as exc:  # raised again in the caller's thread
            step.finished(exc)
        else:
            step.finished()

    threads = [threading.Thread(target=search, args=(i,), daemon=True) for i in range(len(seeds))]
    for t in threads:
        t.start()
    with tqdm(desc=progress, unit="round", disable=progress is None, leave=False) as bar:
        step.serve(bar)
    for t in threads:
        t.join()
    return {"seeds": seeds, "gains": [[float(v) for v in b[1]] for b in best], "cost": [b[0] for b in best],
            "start_cost": first}


def tune_preview(seeds: Sequence[int], *, task: Task, gauge: str | dict = PREVIEW_TUNING_GAUGE, iters: int = 30,
                 fd_step: float = 0.02, bound: float = 100.0, progress: str | None = None,
                 processes: int = 1) -> dict:
    """The preview feedforward's gains (`control.preview`) minimising the mean cost over the plants `seeds`: L-BFGS-B
    from zero (the reference alone) within +-`bound` (tuner's units), each gradient by forward differences of
    `fd_step`, the point and its 17 neighbours run in one batch, or split among `processes` worker processes
    (`distributed.run_jobs`; each gain set's episodes are the same in any batch, so the search is the same). Returns
    the gains, their cost, the reference's cost on the same plants and the number of gain sets evaluated."""
    from tqdm.auto import tqdm

    dim = len(FF_CHANNELS)
    n_eval = 0
    best_cost, best_x = math.inf, np.zeros(dim)
    bar = tqdm(desc=progress, unit="eval", disable=progress is None, leave=False)

    def cost_and_grad(x: np.ndarray) -> tuple[float, np.ndarray]:
        nonlocal n_eval, best_cost, best_x
        pts = np.vstack([x, x + fd_step * np.eye(dim)])
        c = _preview_costs_in(processes, pts, seeds, task, gauge)
        n_eval += len(pts)
        bar.update(len(pts))
        if c[0] < best_cost:
            best_cost, best_x = float(c[0]), x.copy()
            bar.set_postfix(best=f"{c[0]:.4f}")
        return float(c[0]), (c[1:] - c[0]) / fd_step

    with bar:
        ref_cost, _ = cost_and_grad(np.zeros(dim))
        optimize.minimize(cost_and_grad, np.zeros(dim), jac=True, method="L-BFGS-B",
                          bounds=[(-bound, bound)] * dim, options={"maxiter": iters, "ftol": 1e-5})
    return {"gains": [float(v) for v in best_x], "tuning_cost": round(best_cost, 4),
            "reference_cost": round(ref_cost, 4), "n_evaluations": n_eval}
