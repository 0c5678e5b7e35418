"""Where a benchmark's episodes run: in this process, in local worker processes (`--jobs`, "auto" decided on the
runs) or on Ray, as jobs of one controller's chunk of plants or its named scenarios. Each episode depends only on its
seeds, so the numbers are the same wherever it runs."""

from __future__ import annotations

from typing import Callable, Mapping, Sequence

from tqdm.auto import tqdm

from millvib_env._checks import integer
from millvib_env.control.base import Controller
from millvib_env.catalog.factory import ControllerSpec, build_controller, load_controller
from millvib_env.catalog.registry import REGISTRY
from millvib_env.distributed import run_jobs, start_workers
from millvib_env.envs.batch import env_version
from millvib_env.tasks import Task
from millvib_env.threads import configured_threads, usable_cores
from millvib_env.evaluation.evaluate import EpisodeRecord, run_episodes
from millvib_env.evaluation.stats import load_library
from millvib_env.evaluation.benchmark.protocol import distinct_plant_scenarios


def episode_records(name: str, task: Task, seeds: list[int], env_id: str = "MillVib-GainSchedule-v0",
                    env_kwargs: dict | None = None, agent_seed: int | None = None) -> list[EpisodeRecord]:
    """One controller's episodes on `seeds` of `task`, by name (a job of a distributed sweep: the Task
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
#: the baselines whose rows take seconds (a QP every sample): --jobs auto runs worker processes where one runs
SLOW_BASELINES = tuple(name for name, b in REGISTRY.items() if b.slow)
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


def _settle_auto(processes: int | str, units: list, loaded: dict, specs: Mapping, n_plants: int,
                 ray: str | None) -> int:
    """`_processes`'s "auto" decided on the runs (`auto_jobs`; none on Ray). `_load_units` left the seeds that
    workers build unbuilt: where the runs stay in this process after all, they are built here from their specs."""
    if processes != "auto":
        return int(processes)
    if ray is not None:
        return 1
    chosen = auto_jobs(units, n_plants)
    if chosen == 1:
        for name, seed in units:
            if (name, seed) not in loaded:
                loaded[(name, seed)] = build_controller(specs[(name, seed)])
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
    """`_scenario_records` of one controller by name (the benchmark's own jobs build theirs from specs,
    `benchmark_job`); an agent on its training seed `agent_seed`, a baseline in `env_id`'s version."""
    return _scenario_records(load_controller(name, task, seed=agent_seed, version=env_version(env_id)), plant,
                             env_kwargs)


def benchmark_job(kind: str, spec: ControllerSpec, env_kwargs: dict | None = None, seeds: list[int] | None = None,
                  plant: int | None = None, **_) -> list[EpisodeRecord] | dict[str, dict]:
    """One job of a distributed benchmark: the controller `spec` names (resolved once, in the benchmark's process)
    built here, and its episodes on plants `seeds` ("episodes") or its named scenarios on `plant` ("scenarios").
    The job's other keys (its controller's name and training seed) are the benchmark's bookkeeping."""
    ctrl = build_controller(spec)
    if kind == "episodes":
        assert seeds is not None
        return _run(ctrl, seeds, env_kwargs)
    assert plant is not None
    return _scenario_records(ctrl, plant, env_kwargs)


def _is_slow(name: str, seed: int | None) -> bool:
    return seed is not None or name in SLOW_BASELINES


def _split_slow(jobs: list[dict]) -> tuple[list[dict], list[dict]]:
    """The jobs of slow rows (`_is_slow`) and the others, each in their order."""
    slow = [_is_slow(j["name"], j["agent_seed"]) for j in jobs]
    return [j for j, s in zip(jobs, slow) if s], [j for j, s in zip(jobs, slow) if not s]


def _collect_records(units: list, loaded: dict, specs: Mapping, plants: list[int], ray: str | None,
                     progress: bool, processes: int = 1, label: str = "benchmark", scenarios: bool = False,
                     complete: Callable[[str, list], None] | None = None, env_kwargs: Mapping[str, dict] | None = None
                     ) -> tuple[dict[tuple, list[EpisodeRecord]], dict[str, dict]]:
    """Every unit's (controller, agent seed) episode records on `plants` and, with `scenarios`, each controller's
    named scenarios on the first plant (its first unit's: an agent's lowest seed). In this process, or as jobs of
    the units' specs (`specs`: each name resolved once, in this process; the workers build from them)
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
        episodes = [{"kind": "episodes", "name": n, "spec": specs[(n, s)], "seeds": chunk, "agent_seed": s,
                     "env_kwargs": kw_of.get(n)}
                    for n, s in units for chunk in _chunks(plants, processes if ray is None else None, s is not None)]
        named = [{"kind": "scenarios", "name": n, "spec": specs[(n, s)], "plant": plants[0], "agent_seed": s,
                  "env_kwargs": kw_of.get(n)} for n, s in scenario_units]
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
