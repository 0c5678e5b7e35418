"""`run_benchmark`: a benchmark's result from its controllers' runs, comparisons, room and information verdict."""

from __future__ import annotations

import sys
import time
from typing import Sequence

from millvib_env._checks import shown
from millvib_env.control.base import Controller
from millvib_env.catalog.registry import REFERENCE, REGISTRY, baseline_names
from millvib_env.envs.config import DEFAULT_VERSION, ENV_VERSIONS
from millvib_env.tasks import Task, takes_task
from millvib_env.evaluation.verdict import information_verdict
from millvib_env.evaluation.benchmark.jobs import _collect_records, _processes, _records_of, _settle_auto
from millvib_env.evaluation.benchmark.lineup import (_load_units, _own_controllers, _preview_kwargs, default_lineup,
                                                     information_of)
from millvib_env.evaluation.benchmark.protocol import (DEFAULT_EPISODES, DEFAULT_PREVIEW_GAUGE, FULL_EPISODES,
                                                       PREVIEW_GAUGES, _header, summarize)
from millvib_env.evaluation.benchmark.comparison import _Early, _compare, room


@takes_task()
def run_benchmark(controllers: Sequence[str | Controller] | None = None, *, task: str | Task = "startup",
                  episodes: int | None = None, seed: int = 0, env_version: str = DEFAULT_VERSION,
                  scenarios: bool | None = None, progress: bool = True, ray: str | None = None,
                  all_seeds: bool = False, reference: str | None = None, jobs: int | str = 1,
                  preview: str = DEFAULT_PREVIEW_GAUGE) -> dict:
    """Evaluate `controllers` (default: every baseline and every agent trained on the task but the retired ones,
    `catalog.agents.agent_retired`) on
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
    it as `preview` says: "measured" (the default: an entry gauge's errors, `envs.gauge`), "exact" or "failed" (the
    gauge's signal lost for the episode). Each
    controller's information set, and each set's classical controller, bound and room, are in the result
    (`evaluation.verdict`)."""

    if env_version not in ENV_VERSIONS:
        raise ValueError(f"--env-version {shown(env_version)} is invalid: one of {list(ENV_VERSIONS)}")
    if preview not in PREVIEW_GAUGES:
        raise ValueError(f"--preview {shown(preview)} is invalid: one of {list(PREVIEW_GAUGES)}")
    assert isinstance(task, Task)  # a name was resolved by @takes_task
    t = task
    if episodes is None:
        episodes = FULL_EPISODES if all_seeds else DEFAULT_EPISODES
    names, own = _own_controllers(controllers, env_version, t) if controllers is not None else \
        (default_lineup(env_version, t), {})
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
    units, loaded, specs = _load_units(names, t, all_seeds, env_version, progress, own,
                                       here=ray is None and processes == 1)
    first_unit = {name: next(u for u in units if u[0] == name and u in loaded) for name in names}
    firsts = {name: loaded[u] for name, u in first_unit.items()}
    result["specs"] = {name: specs[u] for name, u in first_unit.items() if u in specs}  # for the traces' plot
    sets = {name: information_of(name, c, t, env_version) for name, c in firsts.items()}
    extra = _preview_kwargs(firsts, preview)
    processes = _settle_auto(processes, units, loaded, specs, episodes, ray)
    plants = t.heldout_plants(episodes, seed)  # after the controllers: a bad name fails before any work
    result["plants"] = plants
    start = time.time()
    early = _Early(names, reference)
    records, result["scenarios"] = _collect_records(units, loaded, specs, plants, ray, progress, processes, label,
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
