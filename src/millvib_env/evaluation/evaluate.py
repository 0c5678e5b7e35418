"""One evaluation loop for every controller: a batch of episodes on given plants, episode metrics out.

Episode i runs in environment i of a native VecEnv, reset with seed ``seeds[i]`` (and optionally a
scenario), so every controller meets exactly the same plants, disturbances and initial states:
the env draws its plant and disturbances from the seed alone, in either mode. Only each
environment's first episode is recorded.
"""

from __future__ import annotations

import math
from typing import Any, Sequence, TypedDict, cast

import numpy as np

from millvib_env._checks import choice, instance, integer, integers, real, shown
from millvib_env.control.base import Controller
from millvib_env.envs.batch import ENV_IDS, EpisodeBatch
from millvib_env.envs.reward import DIVERGED_COST
from millvib_env.plant.model import IV, IX
from millvib_env.tasks import Task, takes_task

__all__ = ["run_episodes", "episode_cost", "scored_cost", "COST_SCALES", "EpisodeRecord", "RECORD_FIELDS",
           "CSV_FIELDS", "ACTUATOR_FIELDS", "DIVERGED_COST"]


class EpisodeRecord(TypedDict, total=False):
    """One episode as `run_episodes` records it: the one home of its keys, which the statistics
    (`benchmark.summarize`), the benchmark's and the sweep's CSVs read."""

    seed: int                   # the episode seed: the plant, its disturbances and start
    scenario: str | None        # a named scenario, or None for a drawn plant
    c1: float                   # the plant at the episode's start (N s/m, m^3/(s Pa)), ...
    Ct: float
    beta_e: float
    mt: float
    FL: float
    c1_end: float               # ... and at its end (the `change` task moves them)
    Ct_end: float
    severity_mm_s: float        # vibration severity over the episode (ISO-style band RMS)
    tracking_rms_um: float
    iso_zone: str
    diverged: bool
    cost: float                 # `episode_cost`; a diverged episode: at least `DIVERGED_COST`
    command_max_abs_v: float    # the valve command's largest magnitude (V)
    command_at_limit_share: float  # its share of the episode at the amplifier's limit
    spool_stroke_m: float       # the largest port opening (m)
    peak_flow_ratio: float      # the peak valve flow / the valve's rated flow
    pl_min_pa: float            # the chamber pressure's range (Pa)
    pl_max_pa: float
    severity_start_mm_s: float
    severity_rest_mm_s: float
    pump_line_mm_s: float
    low_band_mm_s: float
    episode_return: float
    steps: int
    agent_seed: int | None      # set by the benchmark: the agent's training seed
    c1_log_error: float         # pid-adaptive only (`Controller.episode_extras`): its estimate's error
    ct_log_error: float


RECORD_FIELDS = tuple(EpisodeRecord.__annotations__)
#: the columns of the benchmark's episodes.csv (after "controller"), in order
CSV_FIELDS = ("agent_seed", "seed", "c1", "Ct", "c1_end", "Ct_end", "severity_mm_s", "severity_start_mm_s",
              "severity_rest_mm_s", "pump_line_mm_s", "low_band_mm_s", "tracking_rms_um", "iso_zone", "diverged",
              "cost", "episode_return", "command_max_abs_v", "command_at_limit_share", "spool_stroke_m",
              "peak_flow_ratio", "pl_min_pa", "pl_max_pa", "c1_log_error", "ct_log_error")
#: the actuator's record of an episode (`envs.core.MillVibCore.actuator_metrics`), copied into each record
ACTUATOR_FIELDS = ("command_max_abs_v", "command_at_limit_share", "spool_stroke_m", "peak_flow_ratio", "pl_min_pa",
                   "pl_max_pa")

#: the benchmark's cost: severity / 4.5 mm/s + tracking RMS / 10 um (ISO B/C boundary; 10 um gauge)
COST_SCALES = {"severity_mm_s": 4.5, "tracking_um": 10.0}


def scored_cost(severity_mm_s: float, tracking_rms_um: float, diverged: bool, scales: dict | None = None) -> float:
    """The cost an episode is scored at: `episode_cost`, and for an episode that diverged (left its envelope
    or failed to integrate) at least `envs.reward.DIVERGED_COST`, whatever its short record cost, so failing
    early never pays. Every tuner and the benchmark score episodes with this."""
    cost = episode_cost(severity_mm_s, tracking_rms_um, scales) if math.isfinite(severity_mm_s) else math.inf
    return max(cost, DIVERGED_COST) if diverged else cost


def episode_cost(severity_mm_s: float, tracking_rms_um: float, scales: dict | None = None) -> float:
    """The benchmark's cost of an episode: severity / scale + tracking RMS / scale (`COST_SCALES`)."""
    s = COST_SCALES if scales is None else scales
    if not isinstance(s, dict) or set(s) != set(COST_SCALES):
        raise ValueError(f"scales = {shown(scales)} is invalid: None or a dict with keys {sorted(COST_SCALES)}")
    sev = real("severity_mm_s", severity_mm_s, lo=0.0)
    trk = real("tracking_rms_um", tracking_rms_um, lo=0.0)
    return sev / real("scales['severity_mm_s']", s["severity_mm_s"], lo=0.0, lo_open=True) + \
        trk / real("scales['tracking_um']", s["tracking_um"], lo=0.0, lo_open=True)


@takes_task()
def env_kwargs_for(controller: Controller, task: str | Task | None = None, env_kwargs: dict | None = None) -> dict:
    """The environment keyword arguments a controller runs with on a task (a name or a `Task`; resolved here, where
    `run_episodes` and `trace_episode` take it) (`Controller.env_kwargs_for`)."""
    assert task is None or isinstance(task, Task)  # a name was resolved by @takes_task
    if env_kwargs is not None:
        instance("env_kwargs", env_kwargs, dict, "None or a dict of environment keywords")
    return controller.env_kwargs_for(task, env_kwargs)


def _reset_options(scenario, params, n: int) -> tuple[list[str | None], list[dict | None]]:
    """`run_episodes`'s `scenario` and `params` as one scenario (or None) and one reset options dict (or None) per
    episode."""
    if scenario is None or isinstance(scenario, str):
        scenarios: list[str | None] = [scenario] * n
    elif isinstance(scenario, (list, tuple)) and len(scenario) == n:
        scenarios = list(scenario)
    else:
        raise ValueError(f"scenario = {shown(scenario)} is invalid: a scenario's name, None, or a list of {n} "
                         "(one per seed)")
    if params is None:
        params = [None] * n
    elif not isinstance(params, (list, tuple)) or len(params) != n:
        raise ValueError(f"params = {shown(params)} is invalid: None, or a list of {n} (one dict or None per seed)")
    options = [{**({} if sc is None else {"scenario": sc}), **({} if pp is None else {"params": pp})} or None
               for sc, pp in zip(scenarios, params)]
    return scenarios, options


def run_episodes(controller: Controller, seeds: Sequence[int], *, scenario: str | Sequence[str | None] | None = None,
                 env_id: str | None = None, env_kwargs: dict | None = None, scales: dict | None = None,
                 progress: bool = False, desc: str = "", task: str | Task | None = None,
                 params: Sequence[dict | None] | None = None) -> list[EpisodeRecord]:
    """Run one episode per seed with `controller`; return per-episode metrics (in seed order).

    `task` selects the task's environment config (the controller's own env_kwargs and `env_kwargs`
    are merged on top). Controllers that estimate the plant get every step's measured signals. `scenario`:
    a named scenario for every episode, or one (or None) per seed. `params`: one dict (or None) per seed of plant
    parameters that replace the episode's draw (the reset option ``params``): a plant met again under another
    seed's disturbances.
    """
    instance("controller", controller, Controller, "a Controller (e.g. load_controller('pid-robust'))")
    seeds = integers("seeds", seeds)
    env_id = controller.env_id if env_id is None else choice("env_id", env_id, sorted(ENV_IDS))
    kwargs = env_kwargs_for(controller, task, env_kwargs)
    n = len(seeds)
    scenarios, options = _reset_options(scenario, params, n)
    venv = EpisodeBatch(env_id, n, **kwargs)
    venv.core.record_signals = controller.needs_signals
    if controller.reads_plant:
        controller.attach(venv.core)
    obs = venv.reset(seeds, options)
    controller.on_reset(venv.reset_infos, range(n))
    records: list[EpisodeRecord | None] = [None] * n
    first_params = [dict(info["params"]) for info in venv.reset_infos]
    state = None
    episode_start = np.ones(n, dtype=bool)
    bar = None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=n, desc=desc or controller.name, unit="ep", leave=False)
    core = venv.core
    while any(r is None for r in records):
        action, state = controller.predict(obs, state=state, episode_start=episode_start, deterministic=True)
        # the step that ends every episode still running restarts none: a new episode's draw would be discarded
        last = all(r is not None or core.steps_taken(i) + 1 >= core.settings.max_steps for i, r in enumerate(records))
        obs, dones, infos = venv.step(action, restart=not last)
        episode_start = dones
        controller.on_step(infos)
        finished = np.flatnonzero(dones)
        for i in finished.tolist():
            if records[i] is None:
                info = infos[i]
                sev, trk = float(info["severity"]), float(info["tracking_rms_um"])
                rec = {"seed": int(seeds[i]), "scenario": scenarios[i], "c1": first_params[i]["c1"],
                       "Ct": first_params[i]["Ct"], "beta_e": first_params[i]["beta_e"],
                       "mt": first_params[i]["mt"], "FL": first_params[i]["FL"],
                       "c1_end": info["params"]["c1"], "Ct_end": info["params"]["Ct"],
                       "severity_mm_s": sev, "tracking_rms_um": trk,
                       "iso_zone": info["iso_zone"], "diverged": bool(info["diverged"]),
                       "cost": scored_cost(sev, trk, bool(info["diverged"]), scales),
                       **{k: info[k] for k in ACTUATOR_FIELDS},
                       "severity_start_mm_s": info["severity_start"],
                       "severity_rest_mm_s": info["severity_rest"],
                       "pump_line_mm_s": info["pump_line_mm_s"], "low_band_mm_s": info["low_band_mm_s"],
                       "episode_return": float(info["episode_return"]), "steps": int(info["episode_steps"]),
                       **controller.episode_extras(i)}
                records[i] = cast(EpisodeRecord, rec)
                if bar is not None:
                    bar.update(1)
        if len(finished) and not last:
            controller.on_reset([venv.reset_infos[i] for i in finished], finished)
    if bar is not None:
        bar.close()
    return records  # type: ignore[return-value]


def trace_episode(controller: Controller, *, scenario: str | None = None, seed: int = 0,
                  env_kwargs: dict | None = None, task: str | Task | None = None) -> dict:
    """One episode with every plant sample kept: t, x, v, a, u and the set-point xd (10 kHz) and, in gain
    mode, the gains of every agent step (empty for valve policies)."""

    instance("controller", controller, Controller, "a Controller (e.g. load_controller('pid-robust'))")
    seed = integer("seed", seed, lo=0)
    kwargs = env_kwargs_for(controller, task, env_kwargs)
    venv = EpisodeBatch(controller.env_id, 1, **kwargs)
    venv.core.record_signals = controller.needs_signals
    if controller.reads_plant:
        controller.attach(venv.core)
    obs = venv.reset([seed], {"scenario": scenario} if scenario is not None else None)
    controller.on_reset(venv.reset_infos, [0])
    core = venv.core
    y0 = core.plant_state(slice(0, 1))
    parts: dict[str, list] = {"x": [y0[:, IX]], "v": [y0[:, IV]], "a": [np.zeros(1)], "u": [np.zeros(1)],
                              "xd": [core.setpoint_course(0, slice(0, 1))]}
    gains, state, start = [], None, np.ones(1, dtype=bool)
    while True:
        action, state = controller.predict(obs, state=state, episode_start=start, deterministic=True)
        if core.settings.mode == "gain":
            gains.append(core.gains_from_action(np.asarray(action, dtype=np.float64).reshape(1, -1))[0][:3])
        xd = core.period_setpoint(0)  # before an auto-reset
        obs, done, infos = venv.step(action)
        start = done
        controller.on_step(infos)
        parts["xd"].append(xd)
        for key, samples in core.period_trace(0).items():
            parts[key].append(samples)
        if done[0]:
            break
    out: dict[str, Any] = {k: np.concatenate(v) for k, v in parts.items()}
    out["t"] = np.arange(out["x"].size) * core.settings.dt_sample
    out["gains"] = np.array(gains).reshape(-1, 3)
    out["step_s"] = core.settings.period_s
    out["info"] = infos[0]
    return out
