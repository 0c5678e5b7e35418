"""`millvib benchmark`: every controller of a task on the same held-out plants (and, for `startup`,
on every named scenario).

Held-out plants: `--episodes` episode seeds drawn without replacement from the task's held-out range
(configs/tasks.yaml) by a generator seeded with `--seed`, so no plant is ever a training, tuning or
validation plant; each seed fixes the plant (c1, Ct), the disturbances and the start, identically
in both environment modes, so gain schedulers, valve policies and fixed PIDs meet the same plants.
Agents run with their lowest training seed, or with every seed they ship (`--all-seeds`, the full
protocol). Per controller: cost mean, IQM, CVaR-20, worst episode, severity and tracking means with
95 % intervals (`millvib_env.evaluation.stats`), diverged rate, the paired differences to `pid-robust`
(mean and CVaR-20 cost) with the probability of improvement, the normalised score (0 = pid-robust,
1 = pid-oracle), the spread over training seeds, and the vibration detail (severity quantiles, its
start and the rest, the pump line, the 10-100 Hz band, ISO zones). Cost = severity / 4.5 mm/s + tracking RMS / 10 um.
"""

from __future__ import annotations

import copy
import csv
import io
import json
import math
import sys
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from tqdm.auto import tqdm

from millvib_env._checks import integer, shown
from millvib_env._figures import log_span, panel_grid
from millvib_env._paths import atomic_folder, check_output, check_result_folder, save_figure, write_text_atomic
from millvib_env.control.agents import agent_base, agent_seeds, list_agents
from millvib_env.control.base import Controller
from millvib_env.control.factory import load_controller
from millvib_env.control.information import from_env_kwargs
from millvib_env.control.registry import REFERENCE, REGISTRY, baseline_names
from millvib_env.distributed import run_jobs, start_workers
from millvib_env.envs.batch import env_id_for, env_version
from millvib_env.envs.config import DEFAULT_VERSION, ENV_VERSIONS, EnvConfig
from millvib_env.envs.scenarios import get_scenario, list_scenarios
from millvib_env.plant.model import rated_flow
from millvib_env.tasks import Task, takes_task
from millvib_env.threads import configured_threads, usable_cores
from millvib_env.evaluation.evaluate import COST_SCALES, CSV_FIELDS, EpisodeRecord, run_episodes, trace_episode
from millvib_env.evaluation.stats import (METRICS, cvar, interval, iqm, load_library, normalized_score,
                                          paired_difference)
from millvib_env.evaluation.verdict import format_information, information_verdict

__all__ = ["run_benchmark", "summarize", "format_table", "benchmark_from_cli", "DEFAULT_EPISODES",
           "FULL_EPISODES", "cvar", "interval", "paired_difference"]

#: held-out plants per controller: the quick run (one seed per agent) and the full protocol (--all-seeds)
#: how a benchmark gives a preview to the controllers that read one (`envs.gauge`), and its default
PREVIEW_GAUGES = ("measured", "exact")
DEFAULT_PREVIEW_GAUGE = "measured"


DEFAULT_EPISODES = 40
FULL_EPISODES = 200


def _by_seed(records: Sequence[Mapping[str, Any]]) -> list[list[Mapping[str, Any]]]:
    """Records split by the agent's training seed (`agent_seed`; one group for a fixed controller),
    each group in plant order."""
    groups: dict = {}
    for r in records:
        groups.setdefault(r.get("agent_seed"), []).append(r)
    return [groups[k] for k in sorted(groups, key=lambda k: (k is not None, k if k is not None else -1))]


def summarize(records: Sequence[Mapping[str, Any]]) -> dict:
    """One controller's summary over its episodes (an agent's: every training seed x the plants).
    The protocol's six metrics carry a 95 % interval (`millvib_env.evaluation.stats`)."""
    groups = _by_seed(records)
    sev = np.array([r["severity_mm_s"] for r in records], float)
    trk = np.array([r["tracking_rms_um"] for r in records], float)
    cost = np.array([r["cost"] for r in records], float)
    zones = {z: int(sum(r["iso_zone"] == z for r in records)) for z in "ABCD"}
    per = lambda key: [[r[key] for r in g] for g in groups]  # noqa: E731
    out = {"cost_mean": float(np.mean(cost)), "cost_iqm": iqm(cost), "cost_cvar20": cvar(cost),
           "cost_worst": float(np.max(cost)), "severity_mean": float(np.mean(sev)),
           "tracking_rms_um_mean": float(np.mean(trk)),
           "diverged_rate": float(np.mean([r["diverged"] for r in records])),
           "n_seeds": len(groups), "episodes": len(groups[0]) if groups else 0}
    for metric in ("mean", "iqm", "cvar20", "worst"):
        out[f"cost_{metric}_ci"] = interval(per("cost"), METRICS[metric])
    out["severity_mean_ci"] = interval(per("severity_mm_s"))
    out["tracking_rms_um_mean_ci"] = interval(per("tracking_rms_um"))
    out.update({"cost_median": float(np.median(cost)), "severity_median": float(np.median(sev)),
                "severity_p95": float(np.percentile(sev, 95)), "iso_zones": zones})
    if groups and groups[0][0].get("agent_seed") is not None:
        out["per_seed"] = [{"seed": g[0]["agent_seed"], "cost_mean": float(np.mean([r["cost"] for r in g])),
                            "cost_cvar20": cvar([r["cost"] for r in g]),
                            "severity_mean": float(np.mean([r["severity_mm_s"] for r in g]))} for g in groups]
    out.update(actuator_summary(records))
    for key in ("severity_start_mm_s", "severity_rest_mm_s", "pump_line_mm_s", "low_band_mm_s",
                "c1_log_error", "ct_log_error"):
        vals = [r[key] for r in records if key in r]
        if vals:
            out[key.replace("_mm_s", "") + "_mean"] = float(np.nanmean(vals)) if np.isfinite(vals).any() else math.nan
    return out


def _spread(values) -> dict:
    v = np.asarray(values, float)
    return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(np.max(v))}


def actuator_summary(records: Sequence[Mapping[str, Any]]) -> dict:
    """What a controller asked of its actuator, over its episodes: the valve command's largest magnitude per
    episode (median, p95, max; V) and its mean share of time at the amplifier's limit, the spool stroke used
    (m) and the peak flow against the rated flow (median, p95, max), the chamber pressure's range (Pa), and
    the number of episodes that diverged (scored at least `DIVERGED_COST`)."""
    return {"command": {"max_abs_v": _spread([r["command_max_abs_v"] for r in records]),
                        "share_at_limit": float(np.mean([r["command_at_limit_share"] for r in records]))},
            "spool_stroke_m": _spread([r["spool_stroke_m"] for r in records]),
            "peak_flow_ratio": _spread([r["peak_flow_ratio"] for r in records]),
            "pressure_pa": {"min": float(min(r["pl_min_pa"] for r in records)),
                            "max": float(max(r["pl_max_pa"] for r in records))},
            "n_diverged": int(sum(bool(r["diverged"]) for r in records))}


def loop_description(cfg: EnvConfig) -> dict:
    """The loop an environment config runs (the benchmark JSON's ``loop``): the controller's rate and delay,
    the amplifier's limit, the valve and the sensors; ``analog`` for the paper's continuous loop (v0)."""

    p = cfg.base_params
    valve = ({"natural_frequency_hz": p.valve_wn_hz, "damping": p.valve_zeta, "xv_max_m": p.xv_max,
              "m_per_v": p.xv_per_volt, "rated_flow_m3_s": rated_flow(p)} if not p.ideal_valve else
             {"ideal": True, "xv_max_m": p.xv_max, "m_per_v": p.xv_per_volt, "rated_flow_m3_s": rated_flow(p)})
    finite = lambda v: v if math.isfinite(v) else None  # noqa: E731 (JSON has no infinity: null = no limit)
    valve["xv_max_m"] = finite(valve["xv_max_m"])  # type: ignore[assignment]
    out = {"u_max_v": finite(p.u_max), "valve": valve}
    if cfg.loop is None:
        return {"kind": "analog", **out}
    return {"kind": "digital", **cfg.loop.describe(), **out}


def distinct_plant_scenarios() -> list[str]:
    """The named scenarios with distinct plants (a scenario's own fixed PID plays no part here)."""
    seen, names = set(), []
    for name in list_scenarios():
        sc = get_scenario(name)
        key = (tuple(sorted(sc.params.items())), sc.x0_m)
        if key not in seen:
            seen.add(key)
            names.append(name)
    return names


def episode_records(name: str, task: Task, seeds: list[int], env_id: str = "MillVib-GainSchedule-v0",
                    env_kwargs: dict | None = None, agent_seed: int | None = None) -> list[EpisodeRecord]:
    """One controller's episodes on `seeds` of `task` (a job of a distributed benchmark or sweep: the Task
    crosses to the worker as it is); for an agent, its training seed `agent_seed` (default: the lowest it
    ships), recorded as `agent_seed`. A baseline runs in `env_id`'s version; an agent in its own."""
    ctrl = load_controller(name, task, seed=agent_seed, version=env_version(env_id))
    return _run(ctrl, seeds, env_kwargs)


def _run(ctrl: Controller, seeds, env_kwargs: dict | None = None, **kw) -> list[EpisodeRecord]:
    """`ctrl`'s episodes on `seeds`, on the task it was loaded for (`Controller.task`)."""
    is_agent = ctrl.seed is not None  # a trained policy: an agent, or its exported graph
    recs = run_episodes(ctrl, seeds, env_id=ctrl.env_id, task=ctrl.task, env_kwargs=env_kwargs, **kw)
    if is_agent:
        for r in recs:
            r["agent_seed"] = ctrl.seed
    return recs


#: episodes per job when a benchmark is spread over Ray
CHUNK = 50


def _load_units(names: list[str], task: Task, all_seeds: bool, version: str, progress: bool = False,
                own: Mapping[str, Controller] | None = None,
                here: bool = True) -> tuple[list[tuple[str, int | None]], dict]:
    """The runs of a benchmark, (name, training seed or None for a baseline), and their controllers:
    every agent on its lowest seed, or on every seed it ships (`all_seeds`); a user's `own` controllers as
    they are. Where the runs go to workers (`here` False) only each agent's lowest seed is loaded in this
    process (for its environment and the named scenarios): the workers load the seeds they run."""

    units: list[tuple[str, int | None]] = []
    loaded: dict[tuple, Controller] = {}
    for n in tqdm(names, desc=f"benchmark {task.name}: loading", unit="controller", disable=not progress, leave=False):
        if own and n in own:
            units.append((n, None))
            loaded[(n, None)] = _on_task(own[n], task)
            continue
        first = load_controller(n, task, version=version)
        if first.seed is not None:  # a trained policy (an exported graph holds one seed)
            for s in (agent_seeds(n) if all_seeds and first.card is not None else [first.seed]):
                units.append((n, s))
                if s == first.seed:
                    loaded[(n, s)] = first
                elif here:
                    loaded[(n, s)] = load_controller(n, task, seed=s)
        else:
            units.append((n, None))
            loaded[(n, None)] = first
    return units, loaded


def _on_task(ctrl: Controller, task: Task) -> Controller:
    """A user's controller bound to the benchmark's task (its runs take their environment's config from
    `Controller.task`): the object itself where it was made for that task, else a shallow copy with `task` set,
    so that the user's object is left as it was given."""
    if ctrl.task is task:
        return ctrl
    bound = copy.copy(ctrl)
    bound.task = task
    return bound


def _own_controllers(controllers: Any, version: str, task: Task) -> tuple[list[str], dict[str, Controller]]:
    """`controllers` as names (the groups expanded, `_expand_groups`) and a user's `Controller` objects among
    them, by their names (which must be new: no baseline's or shipped agent's name, each once); each of those runs
    in its own environment, which must be of the benchmark's version."""
    if isinstance(controllers, (str, bytes)) or not isinstance(controllers, (list, tuple)) or not controllers:
        raise ValueError(f"controllers = {shown(controllers)} is invalid: a list of controller names (strings) or "
                         "Controller objects")
    own: dict[str, Controller] = {}
    names: list[str] = []
    taken = set(baseline_names()) | set(list_agents())
    for k, c in enumerate(controllers):
        if isinstance(c, Controller):
            if not isinstance(c.name, str) or not c.name or c.name in taken or c.name in own:
                raise ValueError(f"controllers[{k}].name = {shown(c.name)} is invalid: a new name for your controller "
                                 "(not a baseline's or a shipped agent's, each once)")
            if env_version(c.env_id) != version:
                raise ValueError(f"controllers[{k}] ({c.name}) runs in {c.env_id}, not in environment version "
                                 f"{version}: set its env_id to {env_id_for('gain', version)} or "
                                 f"{env_id_for('valve', version)}, or benchmark in {env_version(c.env_id)}")
            own[c.name] = c
            names.append(c.name)
        elif isinstance(c, str) and c:
            names.append(c)
        else:
            raise ValueError(f"controllers[{k}] = {shown(c)} is invalid: a controller name (a string) or a "
                             "Controller object")
    return _expand_groups(names, version, task), own


def answer_group(version: str, task: Task) -> list[str]:
    """The group 'answer', the mission's question in one table: the paper's fixed-gain PID, the reference, and in
    v1 the classical controller of the preview's information (`ANSWER_CLASSICAL`), the shipped students trained on
    top of it for `task` (their cards' ``on``) and the bound with the same preview (`ANSWER_BOUND`), which gives the
    room."""
    have = baseline_names(version)
    if ANSWER_CLASSICAL not in have:
        return ["pid-paper", REFERENCE]
    learned = [a for a in list_agents(task, version) if agent_base(a) == ANSWER_CLASSICAL]
    return ["pid-paper", REFERENCE, ANSWER_CLASSICAL, *learned, ANSWER_BOUND]


def _expand_groups(names: Sequence[str], version: str, task: Task) -> list[str]:
    """Controller names with the groups 'classical' (`DEPLOYABLE_CLASSICAL`), 'bounds' (the `ROOM_BOUNDS` that
    the version has) and 'answer' (`answer_group`) in place, each name once."""
    have = set(baseline_names(version))
    groups = {"classical": [n for n in DEPLOYABLE_CLASSICAL if n in have],
              "bounds": [n for n in ROOM_BOUNDS if n in have]}
    if "answer" in names:
        groups["answer"] = answer_group(version, task)
    return list(dict.fromkeys(m for n in names for m in groups.get(n, [n])))


#: the baselines whose rows take seconds (a QP every sample): --jobs auto runs worker processes where one runs
SLOW_BASELINES = ("mpc-oracle", "mpc-preview")
#: --jobs auto's most worker processes (measured on 2 cores only: docs/performance.md)
AUTO_JOBS_MAX = 4
#: --jobs auto's fewest plants for worker processes: below it, starting them costs more than they save
AUTO_MIN_PLANTS = 20


def auto_jobs(units: Sequence[tuple[str, int | None]], n_plants: int) -> int:
    """``--jobs auto`` for a benchmark's runs (`_load_units`) on `n_plants` plants: worker processes where an MPC
    bound (`SLOW_BASELINES`) or two agent runs or more (agents x training seeds) take part and there are at least
    `AUTO_MIN_PLANTS` plants, as many as the usable cores, MILLVIB_NUM_THREADS (where the user rations the cores)
    and `AUTO_JOBS_MAX` allow; else 1, this process. An agent runs all its plants in one job, so one agent alone
    gains nothing from a second process. Measured on 2 cores (docs/performance.md, "--jobs auto")."""
    slow = any(seed is None and name in SLOW_BASELINES for name, seed in units)
    agent_runs = sum(seed is not None for _, seed in units)
    if n_plants < AUTO_MIN_PLANTS or not (slow or agent_runs >= 2):
        return 1
    limit = configured_threads()
    return max(1, min(usable_cores(), AUTO_JOBS_MAX, limit if limit is not None else AUTO_JOBS_MAX))


def _processes(jobs: int | str, own: Mapping) -> int | str:
    """`run_benchmark`'s `jobs`, checked: a whole number, or "auto" (`auto_jobs`, decided once the runs are known;
    1 where a controller of the user's own runs, in this process)."""
    if jobs == "auto":
        return 1 if own else "auto"
    jobs = integer("jobs", jobs, lo=1, hi=1024)
    if own and jobs > 1:
        raise ValueError(f"jobs = {jobs} is invalid with a Controller object of your own ({', '.join(own)}): it runs "
                         "in this process; give jobs=1")
    return jobs


def _settle_auto(processes: int | str, units: list, loaded: dict, n_plants: int, ray: str | None, task: Task) -> int:
    """`_processes`'s "auto" decided on the runs (`auto_jobs`; none on Ray). `_load_units` left the seeds that
    workers load unloaded: where the runs stay in this process after all, they are loaded here."""
    if processes != "auto":
        return int(processes)
    if ray is not None:
        return 1
    chosen = auto_jobs(units, n_plants)
    if chosen == 1:
        for name, seed in units:
            if (name, seed) not in loaded:
                loaded[(name, seed)] = load_controller(name, task, seed=seed)
    return chosen


def _chunks(plants: list[int], processes: int | None, agent: bool) -> list[list[int]]:
    """The plants of one controller's jobs. An agent's network acts on the whole batch of plants at once, and its
    actions round differently with the batch's size (a matrix product's blocking), so an agent runs every plant in
    one job: its numbers are the one-process run's. A baseline's plants do not touch each other: CHUNK a job on
    Ray, and on `processes` local workers one share each, so that a slow row (the MPC bounds) is spread out."""
    if agent:
        return [plants]
    size = CHUNK if processes is None else max(1, min(CHUNK, -(-len(plants) // processes)))
    return [plants[i:i + size] for i in range(0, len(plants), size)]


def scenario_records(name: str, task: Task, plant: int, env_id: str = "MillVib-GainSchedule-v0",
                     agent_seed: int | None = None, env_kwargs: dict | None = None) -> dict[str, dict]:
    """`_scenario_records` of one controller by name (a job of a distributed benchmark: the Task crosses to the
    worker as it is); an agent on its training seed `agent_seed`, a baseline in `env_id`'s version."""
    return _scenario_records(load_controller(name, task, seed=agent_seed, version=env_version(env_id)), plant,
                             env_kwargs)


def benchmark_job(kind: str, **job):
    """One job of a distributed benchmark: a controller's episodes on some plants (`episode_records`) or its
    named scenarios (`scenario_records`)."""
    return (episode_records if kind == "episodes" else scenario_records)(**job)


def _is_slow(name: str, seed: int | None) -> bool:
    return seed is not None or name in SLOW_BASELINES


def _split_slow(jobs: list[dict]) -> tuple[list[dict], list[dict]]:
    """The jobs of slow rows (`_is_slow`) and the others, each in their order."""
    slow = [_is_slow(j["name"], j["agent_seed"]) for j in jobs]
    return [j for j, s in zip(jobs, slow) if s], [j for j, s in zip(jobs, slow) if not s]


def _collect_records(units: list, loaded: dict, plants: list[int], env_id: str, ray: str | None,
                     progress: bool, processes: int = 1, label: str = "benchmark", scenarios: bool = False,
                     complete: Callable[[str, list], None] | None = None, env_kwargs: Mapping[str, dict] | None = None
                     ) -> tuple[dict[tuple, list[EpisodeRecord]], dict[str, dict]]:
    """Every unit's (controller, agent seed) episode records on `plants` and, with `scenarios`, each controller's
    named scenarios on the first plant (its first unit's: an agent's lowest seed). In this process, or as jobs
    (`_chunks`, and one per controller's scenarios) on Ray or in `processes` local worker processes: each episode
    depends only on its seeds, so the numbers are the same. The slow rows' jobs (agents, the MPC bounds: episodes
    and scenarios) are submitted first, so that no long job starts at the end, and the short ones after them
    (episodes, then scenarios), the last of which this process may run itself while the workers start. Where the
    runs are jobs, `complete(name, records)` is called in this process as soon as a controller's last episodes come
    in, with the records `_records_of` gives it at the end, while the other jobs run. `env_kwargs`: a controller's
    environment keywords beyond its own, by name (the benchmark's preview setting, `_preview_kwargs`)."""
    kw_of = dict(env_kwargs or {})
    records: dict[tuple, list[EpisodeRecord]] = {}
    firsts: dict[str, tuple] = {}
    for n, s in units if scenarios else []:
        if (n, s) in loaded:
            firsts.setdefault(n, (n, s))
    scenario_units = list(firsts.values())
    if ray is not None or processes > 1:
        task_of = {n: c.task for (n, _), c in loaded.items()}  # each controller's, bound where it was loaded
        episodes = [{"kind": "episodes", "name": n, "task": task_of[n], "seeds": chunk, "env_id": env_id,
                     "agent_seed": s, "env_kwargs": kw_of.get(n)}
                    for n, s in units for chunk in _chunks(plants, processes if ray is None else None, s is not None)]
        named = [{"kind": "scenarios", "name": n, "task": task_of[n], "plant": plants[0], "env_id": env_id,
                  "agent_seed": s, "env_kwargs": kw_of.get(n)} for n, s in scenario_units]
        (slow_named, named), (slow_episodes, episodes) = _split_slow(named), _split_slow(episodes)
        jobs = slow_named + slow_episodes + episodes + named
        # an SB3 agent's workers import torch and SB3 once (an exported graph needs neither)
        agents = any(c.card is not None for c in loaded.values())
        preload = ("torch", "stable_baselines3") if agents else ()
        if ray is None:
            start_workers(benchmark_job, preload)  # its imports run beside this process's own
            load_library()  # the summaries' statistics (`complete`), imported while the workers start
        left = {n: sum(j["kind"] == "episodes" and j["name"] == n for j in jobs) for n, _ in units}
        arrived: dict[int, list] = {}

        def on_result(i: int, part) -> None:
            job = jobs[i]
            if complete is None or job["kind"] != "episodes":
                return
            arrived[i] = part
            left[job["name"]] -= 1
            if left[job["name"]] == 0:  # the jobs in their order: as `_records_of` finds them below
                complete(job["name"], [r for k, j in enumerate(jobs) if j["kind"] == "episodes"
                                       and j["name"] == job["name"] for r in arrived.pop(k)])

        parts = run_jobs(benchmark_job, jobs, ray=ray, processes=processes, progress=progress,
                         desc=f"{label} ({'ray' if ray is not None else f'{processes} processes'})",
                         preload=preload, on_result=on_result,  # the short jobs may run here meanwhile
                         meanwhile=[i for i, j in enumerate(jobs) if not _is_slow(j["name"], j["agent_seed"])])
        found = {}
        for job, part in zip(jobs, parts):
            if job["kind"] == "episodes":
                records.setdefault((job["name"], job["agent_seed"]), []).extend(part)
            else:
                found[job["name"]] = part
        return records, {n: found[n] for n, _ in scenario_units}
    for unit in tqdm(units, desc=label, unit="run", disable=not progress):
        records[unit] = _run(loaded[unit], plants, kw_of.get(unit[0]))
    return records, {n: _scenario_records(loaded[(n, s)], plants[0], kw_of.get(n))
                     for n, s in tqdm(scenario_units, desc=f"{label}: scenarios", unit="controller",
                                      disable=not progress, leave=False)}


def _records_of(records: Mapping[tuple, list[EpisodeRecord]], name: str) -> list[EpisodeRecord]:
    """A controller's records, its units' (training seeds') in turn."""
    return [r for (n, _), part in records.items() if n == name for r in part]


def _scenario_records(ctrl, plant: int, env_kwargs: dict | None = None) -> dict[str, dict]:
    """One episode of `ctrl` per named scenario with distinct plants: severity, tracking, zone, divergence, cost.
    A controller whose environments do not touch each other (`Controller.batch_exact`: the baselines) runs them
    as one batch, with the numbers of one at a time; any other one at a time."""
    names = list(distinct_plant_scenarios())
    if ctrl.batch_exact:
        recs = _run(ctrl, [plant] * len(names), env_kwargs, scenario=names)
    else:
        recs = [_run(ctrl, [plant], env_kwargs, scenario=sc)[0] for sc in names]
    return {sc: {k: rec[k] for k in ("severity_mm_s", "tracking_rms_um", "iso_zone", "diverged", "cost")}
            for sc, rec in zip(names, recs)}


def _header(task: Task, version: str, reference: str, seed: int, episodes: int, all_seeds: bool) -> dict:
    """A benchmark's result before its runs: what it runs and on which loop."""
    return {"controllers": {}, "task": task.name, "reference": reference, "seed": seed, "episodes": episodes,
            "env_id": env_id_for("gain", version), "env_version": version,
            "loop": loop_description(task.configs[version]), "all_seeds": bool(all_seeds), "plants": [],
            "cost_scales": dict(COST_SCALES), "scenarios": {}, "records": {}}


@takes_task()
def run_benchmark(controllers: Sequence[str | Controller] | None = None, *, task: str | Task = "startup",
                  episodes: int | None = None, seed: int = 0, env_version: str = DEFAULT_VERSION,
                  scenarios: bool | None = None, progress: bool = True, ray: str | None = None,
                  all_seeds: bool = False, reference: str | None = None, jobs: int | str = 1,
                  preview: str = DEFAULT_PREVIEW_GAUGE) -> dict:
    """Evaluate `controllers` (default: every baseline and every agent trained on the task) on
    `episodes` held-out plants of `task` drawn by a generator seeded with `seed`
    (`Task.heldout_plants`). Agents run with their lowest training seed, or with every seed they
    ship (`all_seeds`, the full protocol; its default is FULL_EPISODES plants, DEFAULT_EPISODES
    otherwise). With `ray` (an address, or "" for a local cluster) controllers x seeds x chunks of
    CHUNK episodes run as Ray tasks; each episode depends only on its seeds, so the numbers are the
    local run's; with `jobs` > 1 they run so in that many local worker processes (`distributed.run_jobs`), with
    the same numbers ("auto": `auto_jobs`, processes where an agent or an MPC bound runs). Every controller is
    compared on the same plants with `reference` (default `REFERENCE`, pid-pf-robust: the strongest deployable
    classical controller; run even where `controllers` leaves it out) and with pid-robust. Baselines run in
    environment version `env_version` (v1: the loop as commissioned; v0: the paper's analog loop), with the gains
    tuned for it; the default controllers are the baselines and the agents trained in that version. A controller
    of your own (a `control.base.Controller` with a new `name`, its `env_id`, `env_kwargs` and `predict`) may stand
    in the list beside the names: it runs in its own environment, in this process (not with `ray`), and is
    compared as any other (docs/benchmark.md). Every controller that reads a preview through its observation reads
    it as `preview` says: "measured" (the default: an entry gauge's errors, `envs.gauge`) or "exact". Each
    controller's information set, and each set's classical controller, bound and room, are in the result
    (`evaluation.verdict`)."""

    if env_version not in ENV_VERSIONS:
        raise ValueError(f"--env-version {shown(env_version)} is invalid: one of {list(ENV_VERSIONS)}")
    if preview not in PREVIEW_GAUGES:
        raise ValueError(f"--preview {shown(preview)} is invalid: one of {list(PREVIEW_GAUGES)}")
    env_id = env_id_for("gain", env_version)
    assert isinstance(task, Task)  # a name was resolved by @takes_task
    t = task
    if episodes is None:
        episodes = FULL_EPISODES if all_seeds else DEFAULT_EPISODES
    names, own = _own_controllers(controllers, env_version, t) if controllers is not None else \
        (baseline_names(env_version) + list_agents(t.name, env_version), {})
    if own and ray is not None:
        raise ValueError(f"ray = {shown(ray)} is invalid with a Controller object of your own ({', '.join(own)}): "
                         "it runs in this process; give ray=None")
    reference = REFERENCE if reference is None else reference
    if not isinstance(reference, str) or not reference:
        raise ValueError(f"--reference {shown(reference)} is invalid: a baseline {baseline_names()} or an agent")
    if reference not in names:
        names = [reference] + names  # loaded first: an unknown name fails at once, in one line
    processes = _processes(jobs, own)
    if scenarios is None:
        scenarios = t.name == "startup"  # the named scenarios are the paper's 1 mm starts
    result = _header(t, env_version, reference, seed, episodes, all_seeds)
    result["preview"] = preview
    label = f"benchmark {t.name}"
    units, loaded = _load_units(names, t, all_seeds, env_version, progress, own, here=ray is None and processes == 1)
    firsts = {name: loaded[next(u for u in units if u[0] == name and u in loaded)] for name in names}
    sets = {name: information_of(name, c, t, env_version) for name, c in firsts.items()}
    extra = _preview_kwargs(firsts, preview)
    processes = _settle_auto(processes, units, loaded, episodes, ray, t)
    plants = t.heldout_plants(episodes, seed)  # after the controllers: a bad name fails before any work
    result["plants"] = plants
    start = time.time()
    early = _Early(names, reference)
    records, result["scenarios"] = _collect_records(units, loaded, plants, env_id, ray, progress, processes, label,
                                                    scenarios=scenarios, complete=early, env_kwargs=extra)
    for name in names:
        recs = _records_of(records, name)
        result["controllers"][name] = {**(early.summaries[name] if name in early.summaries else summarize(recs)),
                                       "env_id": firsts[name].env_id}
        result["records"][name] = recs
    if progress:
        print(f"{label}: paired intervals (bootstrap) ...", file=sys.stderr, flush=True)
    _compare(result, early.comparisons)
    result["room"] = room(result)
    result["information"] = information_verdict(result, sets, baselines={n for n in names if n in REGISTRY})
    result["wall_time_s"] = round(time.time() - start, 1)  # printed; not part of the result files
    return result


def information_of(name: str, ctrl: Controller, task: Task, version: str) -> str:
    """What controller `name` reads (`control.information`): a baseline's declared set, else the set its
    environment's observation gives it (an agent's card, an exported graph, a user's controller)."""
    if name in REGISTRY:
        return REGISTRY[name].information
    cfg = task.configs[version]
    return from_env_kwargs(ctrl.env_kwargs, cfg.observation, reads_plant=ctrl.reads_plant)


def _reads_preview(ctrl: Controller) -> bool:
    """The controller reads a preview through its observation (its environment names look-aheads)."""
    seen = ctrl.env_kwargs.get("observation") if isinstance(ctrl.env_kwargs, dict) else None
    return isinstance(seen, dict) and bool(seen.get("preview_samples"))


def _preview_kwargs(ctrls: Mapping[str, Controller], preview: str) -> dict[str, dict]:
    """The environment keywords that give each preview reader the benchmark's preview, whatever its own card says
    (a student that learned on the measured preview runs on the exact one under ``--preview exact``)."""
    return {n: {"observation": {"preview_gauge": preview}} for n, c in ctrls.items() if _reads_preview(c)}


#: the bounds the room is measured with: controllers that know the plant (not deployable), each with what it
#: stands for; the first group measures the room without preview, mpc-preview with it
ROOM_BOUNDS = {"pid-pf-oracle": "the per-plant re-tuned classical controller (PID + pressure feedback)",
               "lqr-oracle": "a per-plant LQR with integral action",
               "mpc-oracle": "model-predictive control with the plant's state, within +-u_max",
               "mpc-preview": "mpc-oracle with the disturbances' course over its horizon (a preview)"}
#: the group 'answer' (`answer_group`): the classical controller of the students' information and its bound
ANSWER_CLASSICAL, ANSWER_BOUND = "pid-pf-preview", "mpc-preview"
#: the deployable classical controllers, among which the best is named
DEPLOYABLE_CLASSICAL = ("pid-paper", "pid-nominal", "pid-robust", "pid-adaptive", "pid-pf-robust", "pid-pf-ff",
                        "pid-pf-preview")
#: a room below this share of the reference's cost is reported as such, without shares (a ratio to a room of
#: a few tenths of a percent is noise over noise)
ROOM_THRESHOLD = 0.03


def room(result: dict) -> dict | None:
    """The room to learn on the benchmark's plants (`result["room"]`): for each bound of `ROOM_BOUNDS` that ran,
    room = (reference - bound) / reference on the mean and on the CVaR-20 with its paired 95 % interval; the
    room without preview is the largest of the bounds that know only the present (a lower bound on what a
    controller of any structure could gain: a better oracle would show more), the room with preview
    mpc-preview's. Where a room is at least `ROOM_THRESHOLD`, every controller's share of it: its mean improvement
    over the reference divided by the bound's (`stats.normalized_score` against the reference and the bound, with
    its interval), and the same ratio on the CVaR-20 (where that room is positive). The best deployable
    classical controller is named."""
    recs_of, ctrls = result["records"], result["controllers"]
    ref = result.get("reference")
    if ref not in recs_of:
        return None
    bounds = {}
    for name in ROOM_BOUNDS:
        pr = ctrls.get(name, {}).get("paired", {}).get(ref)
        if pr is None:
            continue
        bounds[name] = {"what": ROOM_BOUNDS[name], "room_mean": -pr["cost_diff_rel"],
                        "room_mean_ci": [-pr["ci"][1], -pr["ci"][0]], "room_cvar20": -pr["cvar20_diff_rel"],
                        "room_cvar20_ci": [-pr["cvar20_ci"][1], -pr["cvar20_ci"][0]]}
    if not bounds:
        return None
    present = [n for n in bounds if not REGISTRY[n].previews]
    previews = [n for n in bounds if REGISTRY[n].previews]
    rooms = {}
    if present:
        rooms["without_preview"] = max(present, key=lambda n: bounds[n]["room_mean"])
    if previews:
        rooms["with_preview"] = max(previews, key=lambda n: bounds[n]["room_mean"])
    ref_cost = [r["cost"] for r in recs_of[ref]]
    shares: dict = {}
    for name, recs in recs_of.items():
        if name == ref:
            continue
        costs = [[r["cost"] for r in g] for g in _by_seed(recs)]
        pr = ctrls[name]["paired"][ref]
        shares[name] = {}
        for which, bound in rooms.items():
            b = bounds[bound]
            if b["room_mean"] < ROOM_THRESHOLD:
                continue
            entry: dict = {"bound": bound,
                           "mean": normalized_score(costs, ref_cost, [r["cost"] for r in recs_of[bound]])}
            if b["room_cvar20"] > 0:
                entry["cvar20"] = -pr["cvar20_diff_rel"] / b["room_cvar20"]
            shares[name][which] = entry
    deployable = [n for n in DEPLOYABLE_CLASSICAL if n in ctrls]
    best = min(deployable, key=lambda n: ctrls[n]["cost_mean"]) if deployable else None
    return {"reference": ref, "bounds": bounds, "rooms": rooms, "shares": shares, "best_deployable_classical": best}


def format_room(result: dict) -> str:
    """The room's table (`room`), in markdown; empty where no bound ran."""
    r = result.get("room")
    if not r:
        return ""
    ref = r["reference"]
    pct = lambda v: f"{100 * v:+.1f} %"  # noqa: E731
    lines = [f"The room to learn (against {ref}; room = ({ref} - bound) / {ref}, paired 95 % intervals; a bound "
             "that costs more than the reference gives a negative room):", "",
             "| bound | what it knows | room, mean | room, CVaR-20 |", "|---|---|---|---|"]
    for name, b in r["bounds"].items():
        lines.append(f"| {name} | {b['what']} | {pct(b['room_mean'])} [{pct(b['room_mean_ci'][0])}, "
                     f"{pct(b['room_mean_ci'][1])}] | {pct(b['room_cvar20'])} [{pct(b['room_cvar20_ci'][0])}, "
                     f"{pct(b['room_cvar20_ci'][1])}] |")
    for which, bound in r["rooms"].items():
        b = r["bounds"][bound]
        lines.append(f"\nRoom {which.replace('_', ' ')}: {pct(b['room_mean'])} of the mean "
                     f"[{pct(b['room_mean_ci'][0])}, {pct(b['room_mean_ci'][1])}] ({bound})"
                     + (f": below {100 * ROOM_THRESHOLD:.0f} %. None of the controllers that know the plant and only "
                        "its present (per-plant tuning, LQR, MPC with the true state) finds much to gain here; a "
                        "better bound could show more"
                        if which == "without_preview" and b["room_mean"] < ROOM_THRESHOLD else ""))
    if r.get("best_deployable_classical"):
        lines.append(f"\nBest deployable classical controller: {r['best_deployable_classical']}.")
    heads = [h for h, bound in r["rooms"].items() if r["bounds"][bound]["room_mean"] >= ROOM_THRESHOLD]
    if r["shares"] and heads:
        lines += ["", "Share of the room each controller captures (its improvement over the reference / the bound's; "
                  "mean [interval] and CVaR-20):", "",
                  "| controller | " + " | ".join(f"share {h.replace('_', ' ')}" for h in heads) + " |",
                  "|---|" + "---|" * len(heads)]
        for name, sh in r["shares"].items():
            cells = []
            for h in heads:
                e = sh.get(h, {})
                m = e.get("mean")
                cell = (f"{m['score']:+.2f} [{m['ci'][0]:+.2f}, {m['ci'][1]:+.2f}]" if m else "-")
                cell += f" / {e['cvar20']:+.2f}" if "cvar20" in e else " / -"
                cells.append(cell)
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _comparisons(name: str, recs: list, recs_of: Mapping[str, list], reference: str | None) -> dict:
    """`name`'s paired comparisons on the same plants (`_compare`), from the records of those it is compared with
    (`recs_of`: at least the reference, pid-robust and pid-oracle, where they run)."""
    out: dict[str, Any] = {}
    refs = [n for n in dict.fromkeys([reference, "pid-robust"]) if n is not None and n in recs_of]
    costs = [[r["cost"] for r in g] for g in _by_seed(recs)]
    out["paired"] = {ref: paired_difference(costs, [r["cost"] for r in recs_of[ref]]) for ref in refs if ref != name}
    ref = recs_of.get("pid-robust")
    oracle = recs_of.get("pid-oracle")
    if ref is None:
        return out
    stable = {r["seed"] for r in ref if not r["diverged"]}
    out["diverged_where_pid_robust_stable"] = int(sum(r["diverged"] and r["seed"] in stable for r in recs))
    if name != "pid-robust":
        out["paired_vs_pid_robust"] = out["paired"]["pid-robust"]
    if oracle is not None:
        out["normalized_score"] = normalized_score(costs, [r["cost"] for r in ref], [r["cost"] for r in oracle])
    return out


#: the controllers every other is compared with, where they run (`_comparisons`)
COMPARED_WITH = ("pid-robust", "pid-oracle")


def _compare(result: dict, done: Mapping[str, dict] | None = None) -> None:
    """Paired comparisons on the same plants: per controller `paired` = {reference: ..., "pid-robust":
    ...} (mean and CVaR-20 cost differences with their intervals, P(better)), `paired_vs_pid_robust`
    (the same as paired["pid-robust"], kept for earlier readers) and the normalised score
    (0 = pid-robust, 1 = pid-oracle). `done`: those already made, by controller (`_Early`)."""
    for name, recs in result["records"].items():
        result["controllers"][name].update(done[name] if done and name in done else
                                           _comparisons(name, recs, result["records"], result.get("reference")))


class _Early:
    """A benchmark's summaries and paired comparisons made while its jobs run (`_collect_records`'s `complete`):
    each controller's summary as soon as its last episodes come in, and its comparisons once those it is compared
    with (`COMPARED_WITH` and the reference, where they run) have come in too. The same calls on the same records as
    after the run, so the same numbers."""

    def __init__(self, names: Sequence[str], reference: str):
        self.reference = reference
        self.needed = {reference, *COMPARED_WITH} & set(names)
        self.records: dict[str, list] = {}
        self.summaries: dict[str, dict] = {}
        self.comparisons: dict[str, dict] = {}

    def __call__(self, name: str, recs: list) -> None:
        self.records[name] = recs
        self.summaries[name] = summarize(recs)
        if self.needed <= self.records.keys():
            for n, r in self.records.items():
                if n not in self.comparisons:
                    self.comparisons[n] = _comparisons(n, r, self.records, self.reference)


def _ci(s: dict, key: str, fmt: str = ".3g") -> str:
    lo, hi = s[f"{key}_ci"]
    return f"{s[key]:{fmt}} [{lo:{fmt}}, {hi:{fmt}}]"


def format_table(result: dict) -> str:
    ctrls = result["controllers"]
    seeds_line = ("every training seed of every agent (the full protocol, --all-seeds)" if result.get("all_seeds")
                  else "one training seed per agent (its lowest; the full protocol is --all-seeds)")
    ref = result.get("reference", "pid-robust")
    lines = [f"Task {result.get('task', 'startup')}: {result['episodes']} held-out plants drawn with seed "
             f"{result['seed']}; {seeds_line}. Cost = severity / {result['cost_scales']['severity_mm_s']} mm/s + "
             f"tracking RMS / {result['cost_scales']['tracking_um']} um; IQM = mean of the middle 50 % of episodes; "
             "CVaR-20 = mean of the worst 20 %; [95 % bootstrap intervals: plants resampled within each training "
             f"seed; paired to the reference {ref} (and to pid-robust) on the same plants]. The normalised score "
             "(0 = pid-robust, 1 = pid-oracle) is in the JSON only: where the two cost nearly the same it is "
             "ill-conditioned",
             "",
             f"| controller | seeds | cost mean | cost IQM | cost CVaR-20 | worst episode | vs {ref} | "
             f"CVaR-20 vs {ref} | P(better than {ref}) | vs pid-robust | severity (mm/s) | "
             "tracking RMS (um) | diverged |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    if result.get("title"):  # another command's table (the sweep) names its own plants
        lines[0] = result["title"]

    def pct(d: dict | None, key: str, ci: str) -> str:
        return f"{100 * d[key]:+.1f} % [{100 * d[ci][0]:+.1f}, {100 * d[ci][1]:+.1f}]" if d else "-"

    for name, s in ctrls.items():
        pr = s.get("paired", {}).get(ref)
        robust = s.get("paired", {}).get("pid-robust")
        pb = f"{pr['p_improvement']:.2f}" if pr else "-"
        lines.append(f"| {name} | {s['n_seeds']} | {_ci(s, 'cost_mean')} | {_ci(s, 'cost_iqm')} | "
                     f"{_ci(s, 'cost_cvar20')} | {_ci(s, 'cost_worst')} | {pct(pr, 'cost_diff_rel', 'ci')} | "
                     f"{pct(pr, 'cvar20_diff_rel', 'cvar20_ci')} | {pb} | {pct(robust, 'cost_diff_rel', 'ci')} | "
                     f"{_ci(s, 'severity_mean')} | {_ci(s, 'tracking_rms_um_mean')} | "
                     f"{100 * s['diverged_rate']:.0f} % |")
    oracle = ctrls.get("pid-oracle", {}).get("normalized_score")
    if oracle and oracle.get("one_worse_than_zero"):
        lines.append("\nOn this task pid-oracle (the per-plant best fixed PID) costs more on average than pid-robust, "
                     "so the JSON's normalised score runs the other way: below 0 is better than pid-robust.")
    room_md = format_room(result)
    info_md = format_information(result)
    if info_md:
        room_md = (room_md + "\n\n" + info_md) if room_md else info_md
    if room_md:
        lines += ["", room_md]
    lines += _vibration_rows(ctrls) + _actuator_rows(result) + _spread_rows(ctrls) + _estimate_rows(ctrls)
    lines += _scenario_rows(result)
    return "\n".join(lines)


def _vibration_rows(ctrls: dict) -> list[str]:
    """The table's vibration detail: severity quantiles, where in the episode, the bands, ISO zones."""
    lines: list[str] = []
    lines += ["", "Vibration detail (pooled episodes):", "",
              "| controller | severity median | p95 | first 0.1 s | rest | pump line | 10-100 Hz | zones A/B/C/D |",
              "|---|---|---|---|---|---|---|---|"]
    for name, s in ctrls.items():
        z = s["iso_zones"]
        lines.append(f"| {name} | {s['severity_median']:.3g} | {s['severity_p95']:.3g} | "
                     f"{s.get('severity_start_mean', math.nan):.3g} | {s.get('severity_rest_mean', math.nan):.3g} | "
                     f"{s.get('pump_line_mean', math.nan):.3g} | {s.get('low_band_mean', math.nan):.3g} | "
                     f"{z['A']}/{z['B']}/{z['C']}/{z['D']} |")
    return lines


def _actuator_rows(result: dict) -> list[str]:
    """The actuator's table (where every controller has its command record)."""
    ctrls = result["controllers"]
    lines: list[str] = []
    if all("command" in s for s in ctrls.values()):
        loop = result.get("loop") or {}
        u_max = loop.get("u_max_v")
        lines += ["", f"The actuator ({result.get('env_version', 'v0')}: "
                  + (f"a {loop.get('rate_hz', 0):g} Hz digital loop, " if loop.get("kind") == "digital" else
                     "the paper's analog loop, ")
                  + (f"amplifier limit +-{u_max:g} V" if u_max is not None else "no amplifier limit")
                  + "; per episode, median / p95 / max over the episodes):", "",
                  "| controller | largest command (V) | time at the limit | spool stroke (mm) | peak flow / rated flow "
                  "| chamber pressure (MPa) | diverged episodes |", "|---|---|---|---|---|---|---|"]
        for name, s in ctrls.items():
            c, st, fl, pr = s["command"]["max_abs_v"], s["spool_stroke_m"], s["peak_flow_ratio"], s["pressure_pa"]
            lines.append(f"| {name} | {c['median']:.3g} / {c['p95']:.3g} / {c['max']:.3g} | "
                         f"{100 * s['command']['share_at_limit']:.1f} % | {1e3 * st['median']:.3g} / "
                         f"{1e3 * st['p95']:.3g} / {1e3 * st['max']:.3g} | {fl['median']:.3g} / {fl['p95']:.3g} / "
                         f"{fl['max']:.3g} | {pr['min'] / 1e6:.3g}-{pr['max'] / 1e6:.3g} | {s['n_diverged']} |")
    return lines


def _spread_rows(ctrls: dict) -> list[str]:
    """Each multi-seed agent's mean cost and CVaR-20 per training seed."""
    lines: list[str] = []
    spread = {n: s["per_seed"] for n, s in ctrls.items() if len(s.get("per_seed", [])) > 1}
    if spread:
        lines += ["", "Spread over training seeds (mean cost / CVaR-20 of each seed on the same plants):", "",
                  "| agent | per seed | range of the means |", "|---|---|---|"]
        for name, per in spread.items():
            cells = ", ".join(f"s{p['seed']}: {p['cost_mean']:.3g} / {p['cost_cvar20']:.3g}" for p in per)
            means = [p["cost_mean"] for p in per]
            lines.append(f"| {name} | {cells} | {min(means):.3g}-{max(means):.3g} |")
    return lines


def _estimate_rows(ctrls: dict) -> list[str]:
    """The estimation error of the controllers that estimate the plant (pid-adaptive)."""
    lines: list[str] = []
    est = {n: s for n, s in ctrls.items() if "c1_log_error_mean" in s}
    for name, s in est.items():
        lines.append(f"\n{name}: mean estimation error over the episodes |log10(estimate / true)|: c1 "
                     f"{s['c1_log_error_mean']:.3f}, Ct {s['ct_log_error_mean']:.3f} (decades)")
    return lines


def _scenario_rows(result: dict) -> list[str]:
    """The named scenarios' table: severity and tracking per scenario and controller."""
    lines: list[str] = []
    if result.get("scenarios"):
        names = list(result["scenarios"])
        scen = list(next(iter(result["scenarios"].values())))
        lines += ["", "Named scenarios with distinct plants, one episode each (severity mm/s / tracking RMS um):", "",
                  "| scenario | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for sc in scen:
            cells = []
            for n in names:
                r = result["scenarios"][n][sc]
                cells.append(("diverged " if r["diverged"] else "") + f"{r['severity_mm_s']:.3g} / "
                             f"{r['tracking_rms_um']:.3g}")
            lines.append(f"| {sc} | " + " | ".join(cells) + " |")
    return lines


def public_json(result: dict) -> dict:
    """The summary without the per-episode records (those go to the CSV) and without timings, so the
    same inputs give the same bytes."""
    return {k: v for k, v in result.items() if k not in ("records", "wall_time_s")}


def _write_outputs(result: dict, out: Path, task: Task, figures: bool = True) -> list[Path]:
    """Write the result folder of a benchmark of `task` as a whole: into a temporary sibling, then put in place
    (`atomic_folder`), so an interrupted or concurrent run never leaves a mix of two runs' files. Without
    `figures`, the data files only."""

    with atomic_folder(out, command="benchmark") as tmp:
        files = _write_files(result, tmp, task, figures)
    return [out / f.name for f in files]


def _write_files(result: dict, out: Path, task: Task, figures: bool = True) -> list[Path]:
    files = []
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=["controller", *CSV_FIELDS], extrasaction="ignore")
    writer.writeheader()
    for name, recs in result["records"].items():
        for r in recs:
            writer.writerow({"controller": name, **r})
    files.append(write_text_atomic(out / "episodes.csv", buf.getvalue()))
    files.append(write_text_atomic(out / "benchmark.md", format_table(result) + "\n"))
    files.append(write_text_atomic(out / "benchmark.json", json.dumps(public_json(result), indent=2)))
    if not figures:
        return files
    files.append(_plot_plane(result, out / "severity_plane.png"))
    if result.get("reference", "pid-robust") in result["records"] and len(result["records"]) > 1:
        files.append(_plot_paired_plane(result, out / "paired_plane.png"))
    files.append(_plot_bars(result, out / "cost_bars.png"))
    if task.name == "startup":
        files.append(_plot_traces(list(result["controllers"]), out / f"traces_{TRACE_SCENARIO}.png",
                                  result["plants"][0], task=task, version=result.get("env_version", "v0"),
                                  preview=result.get("preview", "exact")))
    else:
        files.append(_plot_traces(list(result["controllers"]), out / "traces.png", result["plants"][0],
                                  scenario=None, task=task, version=result.get("env_version", "v0"),
                                  preview=result.get("preview", "exact")))
    return files


#: the failure scenario whose time traces the benchmark draws (fixed PIDs against agents)
TRACE_SCENARIO = "low-damping-high-leakage"


def _plot_traces(names: Sequence[str], path: Path, seed: int, *, task: Task, scenario: str | None = TRACE_SCENARIO,
                 version: str = DEFAULT_VERSION, preview: str = "exact") -> Path:
    import matplotlib

    matplotlib.use("Agg")

    fig, grid, _ = panel_grid(4, 1, width=10, height=2.5, colorbar=False, margins=(0.85, 0.2, 0.55, 0.35),
                              sharex=True)
    axes = grid[:, 0]
    u_max = task.configs[version].base_params.u_max
    for k, name in enumerate(names):
        color = f"C{k % 10}"
        ctrl = load_controller(name, task, version=version)
        tr = trace_episode(ctrl, scenario=scenario, seed=seed, task=task,
                           env_kwargs=_preview_kwargs({name: ctrl}, preview).get(name))
        info = tr["info"]
        label = f"{name}: {info['severity']:.3g} mm/s, {info['tracking_rms_um']:.3g} um"
        axes[0].plot(tr["t"] * 1e3, tr["x"] * 1e6, lw=0.8, label=label, color=color)
        axes[1].plot(tr["t"] * 1e3, tr["v"] * 1e3, lw=0.6, color=color)
        axes[2].plot(tr["t"] * 1e3, tr["u"], lw=0.6, color=color)
        if len(tr["gains"]):
            steps = np.arange(len(tr["gains"])) * tr["step_s"] * 1e3
            kp = tr["gains"][:, 0]
            axes[3].step(steps, np.log10(np.where(kp > 0, kp, np.nan)), where="post", lw=1.0, color=color)
    if math.isfinite(u_max):  # the amplifier's rated range: no command leaves it
        for sign in (-1, 1):
            axes[2].axhline(sign * u_max, color="k", ls="--", lw=0.8)
    if scenario is not None:
        axes[0].set(ylabel="x (um)", title=f"Scenario '{scenario}' (c1 and Ct at their worst, 1 mm start): "
                                           "fixed PIDs against agents")
        axes[0].set_ylim(-600, 1050)
    else:
        plant = ", ".join(f"{k} = {v:.3g}" for k, v in tr["info"]["params"].items() if isinstance(v, (int, float)))
        title = f"Task '{task.name}', held-out plant {seed}: {plant}"
        axes[0].set(ylabel="x (um)", title=title if len(title) <= 120 else title[:title.rindex(", ", 0, 120)] + ", ...")
        axes[0].title.set_fontsize(9)
    axes[0].legend(fontsize=8)
    axes[1].set(ylabel="v (mm/s)")
    axes[2].set(ylabel="u (V)", title="valve command" + (f" (the amplifier's +-{u_max:g} V dashed)"
                                                          if math.isfinite(u_max) else ""))
    axes[3].set(ylabel="log10 KP", title="the PID's KP (gain schedules; gaps: KP <= 0)", xlabel="t (ms)")
    for ax in axes:
        ax.grid(alpha=0.3)
    return save_figure(fig, path, dpi=100)


def _plot_plane(result: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.colors import LogNorm

    names = list(result["records"])
    cols = min(3, len(names))
    rows = math.ceil(len(names) / cols)
    fig, axes, cax = panel_grid(rows, cols, width=4.8, height=4.2)
    all_sev = [r["severity_mm_s"] for recs in result["records"].values() for r in recs]
    norm = LogNorm(vmin=max(min(all_sev), 1e-2), vmax=max(all_sev))
    for ax, name in zip(axes.flat, names):
        recs = _by_seed(result["records"][name])[0]  # an agent's lowest seed
        sc = ax.scatter([r["Ct"] for r in recs], [r["c1"] for r in recs], c=[r["severity_mm_s"] for r in recs],
                        norm=norm, cmap="magma_r", s=40, edgecolors="k", linewidths=0.3)
        for r in recs:
            if r["diverged"]:
                ax.scatter(r["Ct"], r["c1"], marker="x", color="red", s=60)
        s = result["controllers"][name]
        log_span(ax, "x", [r["Ct"] for r in recs])
        log_span(ax, "y", [r["c1"] for r in recs])
        ax.set(xlabel="Ct (m^3/(s Pa))", ylabel="c1 (N s/m)",
               title=f"{name}\nmean {s['severity_mean']:.3g} mm/s, cost {s['cost_mean']:.3g}")
        ax.title.set_fontsize(9)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    fig.colorbar(sc, cax=cax, label="episode severity (mm/s)")
    return save_figure(fig, path, dpi=100)


def _plot_paired_plane(result: dict, path: Path) -> Path:
    """Per plant, each controller's cost relative to the reference's on that plant (mean over an
    agent's seeds), over the (Ct, c1) plane: where learning or adaptation helps and where not."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.colors import TwoSlopeNorm

    ref_name = result.get("reference", "pid-robust")
    ref = {r["seed"]: r for r in result["records"][ref_name]}
    names = [n for n in result["records"] if n != ref_name]
    cols = min(3, len(names))
    rows = math.ceil(len(names) / cols)
    fig, axes, cax = panel_grid(rows, cols, width=4.8, height=4.2, suptitle=0.45)
    diffs = {}
    for name in names:
        per_plant: dict = {}
        for r in result["records"][name]:
            per_plant.setdefault(r["seed"], []).append(r["cost"])
        diffs[name] = {k: 100 * (np.mean(v) / ref[k]["cost"] - 1) for k, v in per_plant.items()}
    lim = 40.0  # % either way; beyond it the colour saturates (pid-paper is several times dearer)
    norm = TwoSlopeNorm(vcenter=0.0, vmin=-lim, vmax=lim)
    for ax, name in zip(axes.flat, names):
        keys = list(diffs[name])
        sc = ax.scatter([ref[k]["Ct"] for k in keys], [ref[k]["c1"] for k in keys], c=[diffs[name][k] for k in keys],
                        norm=norm, cmap="RdBu_r", s=28, edgecolors="k", linewidths=0.2)
        pr = result["controllers"][name].get("paired", {}).get(ref_name, {})
        log_span(ax, "x", [ref[k]["Ct"] for k in keys])
        log_span(ax, "y", [ref[k]["c1"] for k in keys])
        ax.set(xlabel="Ct (m^3/(s Pa))", ylabel="c1 (N s/m)",
               title=f"{name} ({result['controllers'][name]['n_seeds']} seed(s))\nmean "
                     f"{100 * pr.get('cost_diff_rel', math.nan):+.1f} %, better on "
                     f"{100 * pr.get('p_improvement', math.nan):.0f} % of episodes")
        ax.title.set_fontsize(9)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    fig.colorbar(sc, cax=cax, label=f"cost vs {ref_name} on the plant (%, blue = cheaper)", extend="both")
    fig.suptitle(f"Task {result['task']}: paired cost difference to {ref_name} per held-out plant "
                 "(c1, Ct at the episode start)", fontsize=10)
    return save_figure(fig, path, dpi=100)


def _plot_bars(result: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")

    names = list(result["controllers"])
    fig, grid, _ = panel_grid(1, 3, width=13 / 3, height=4.6, colorbar=False, margins=(0.7, 0.2, 1.2, 0.35))
    for ax, key, label in zip(grid[0], ("severity_mean", "tracking_rms_um_mean", "cost_mean"),
                              ("mean severity (mm/s)", "mean tracking RMS (um)", "mean cost")):
        ax.bar(range(len(names)), [result["controllers"][n][key] for n in names], color="tab:blue")
        ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
        ax.set_title(label)
        ax.grid(alpha=0.3, axis="y")
    return save_figure(fig, path, dpi=100)


#: `millvib headroom`'s controllers: the deployable classical ones and every bound
HEADROOM_CONTROLLERS = DEPLOYABLE_CLASSICAL + tuple(ROOM_BOUNDS)


def headroom_from_cli(args) -> int:
    """`millvib headroom`: the benchmark of the deployable classical controllers and the bounds on v1, with the
    room to learn (`room`) printed first."""
    if args.env_version != "v1":
        raise ValueError(f"--env-version {args.env_version} is invalid for headroom: the bounds run on the loop as "
                         "commissioned, v1")
    if args.controllers is None:
        args.controllers = list(HEADROOM_CONTROLLERS)
    return benchmark_from_cli(args)


def benchmark_from_cli(args) -> int:

    check_output(args.json, "--json")
    check_result_folder(args.out, "--out", "benchmark", others=(("--json", args.json),))
    if args.episodes is not None and args.episodes < 1:
        raise ValueError(f"--episodes {args.episodes} is invalid: at least 1")
    if args.seed < 0:
        raise ValueError(f"--seed {args.seed} is invalid: a whole number >= 0 (it seeds the draw of held-out plants)")
    result = run_benchmark(args.controllers, task=args.task, episodes=args.episodes, seed=args.seed,
                           env_version=args.env_version,
                           scenarios=False if args.no_scenarios else None, progress=not args.quiet, ray=args.ray,
                           all_seeds=args.all_seeds, reference=args.reference, jobs=args.jobs,
                           preview=getattr(args, "preview", DEFAULT_PREVIEW_GAUGE))
    print(format_table(result))
    print(f"\n({result['wall_time_s']} s)")
    if args.json:
        write_text_atomic(args.json, json.dumps(public_json(result), indent=2))
        print(f"wrote {args.json}")
    if args.out:
        files = _write_outputs(result, Path(args.out), args.task, figures=not args.no_figures)  # the CLI's Task
        print(f"wrote {len(files)} files to {args.out}")
    return 0
