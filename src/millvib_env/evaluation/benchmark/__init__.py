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

The package's modules, one concern each: `protocol` (plants, previews, the summary of a controller's episodes),
`lineup` (which controllers run, and what each reads), `jobs` (where the episodes run: here, in worker processes,
on Ray), `comparison` (paired comparisons and the room to learn), `run` (`run_benchmark`), `report` (tables and JSON),
`plots` (figures), `command` (the CLI's commands) and `flags` (their arguments). The public names below are
importable from the package itself, each loaded from its module at its first use, so that the CLI's parser, which
imports `flags`, does not import the benchmark.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from millvib_env.evaluation.benchmark.command import (HEADROOM_CONTROLLERS, benchmark_from_cli, episode_costs,
                                                          headroom_from_cli)
    from millvib_env.evaluation.benchmark.jobs import (AUTO_JOBS_MAX, AUTO_MIN_PLANTS, CHUNK, SLOW_BASELINES,
                                                       auto_jobs, benchmark_job, episode_records, scenario_records)
    from millvib_env.evaluation.benchmark.lineup import (ANSWER_BOUND, ANSWER_CLASSICAL, DEPLOYABLE_CLASSICAL,
                                                         ROOM_BOUNDS, answer_group, information_of)
    from millvib_env.evaluation.benchmark.plots import TRACE_SCENARIO
    from millvib_env.evaluation.benchmark.protocol import (DEFAULT_EPISODES, DEFAULT_PREVIEW_GAUGE, FULL_EPISODES,
                                                           PREVIEW_GAUGES, actuator_summary, distinct_plant_scenarios,
                                                           loop_description, summarize)
    from millvib_env.evaluation.benchmark.report import format_table, public_json
    from millvib_env.evaluation.benchmark.comparison import COMPARED_WITH, ROOM_THRESHOLD, format_room, room
    from millvib_env.evaluation.benchmark.run import run_benchmark
    from millvib_env.evaluation.stats import cvar, interval, paired_difference

__all__ = ["HEADROOM_CONTROLLERS", "benchmark_from_cli", "episode_costs", "headroom_from_cli",
           "AUTO_JOBS_MAX", "AUTO_MIN_PLANTS", "CHUNK", "SLOW_BASELINES", "auto_jobs", "benchmark_job",
           "episode_records", "scenario_records",
           "ANSWER_BOUND", "ANSWER_CLASSICAL", "DEPLOYABLE_CLASSICAL", "ROOM_BOUNDS", "answer_group", "information_of",
           "TRACE_SCENARIO",
           "DEFAULT_EPISODES", "DEFAULT_PREVIEW_GAUGE", "FULL_EPISODES", "PREVIEW_GAUGES", "actuator_summary",
           "distinct_plant_scenarios", "loop_description", "summarize",
           "format_table", "public_json",
           "COMPARED_WITH", "ROOM_THRESHOLD", "format_room", "room",
           "run_benchmark",
           "cvar", "interval", "paired_difference"]

#: each public name's module (the statistics' names are `evaluation.stats`'); a test holds it to `__all__`
_MODULE = {name: module for module, names in {
    "command": ("HEADROOM_CONTROLLERS", "benchmark_from_cli", "episode_costs", "headroom_from_cli"),
    "jobs": ("AUTO_JOBS_MAX", "AUTO_MIN_PLANTS", "CHUNK", "SLOW_BASELINES", "auto_jobs", "benchmark_job",
             "episode_records", "scenario_records"),
    "lineup": ("ANSWER_BOUND", "ANSWER_CLASSICAL", "DEPLOYABLE_CLASSICAL", "ROOM_BOUNDS", "answer_group",
               "information_of"),
    "plots": ("TRACE_SCENARIO",),
    "protocol": ("DEFAULT_EPISODES", "DEFAULT_PREVIEW_GAUGE", "FULL_EPISODES", "PREVIEW_GAUGES", "actuator_summary",
                 "distinct_plant_scenarios", "loop_description", "summarize"),
    "report": ("format_table", "public_json"),
    "comparison": ("COMPARED_WITH", "ROOM_THRESHOLD", "format_room", "room"),
    "run": ("run_benchmark",),
}.items() for name in names}


def __getattr__(name: str) -> Any:
    """A public name, from its module (imported at the first use of any of its names)."""
    if name not in __all__:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    where = f"{__name__}.{_MODULE[name]}" if name in _MODULE else "millvib_env.evaluation.stats"
    return getattr(importlib.import_module(where), name)


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
