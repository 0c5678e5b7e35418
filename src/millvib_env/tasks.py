"""The benchmark's tasks (startup, rolling, change) and their disjoint seed ranges (configs/tasks.yaml).

A task is an environment config (`Task.configs`, one per environment version) plus four seed ranges: training,
tuning, validation and held-out. Everything that draws plants for a purpose (training, PID tuning, model cards, the
benchmark) takes its seeds from here, so no held-out plant is ever trained or tuned on.

A task name becomes a `Task` once, where it enters: the CLI, an API entry point (`takes_task`), a file that names
a task. Below them the `Task` is passed down, and what it carries (its configs, seeds) is read from it.
"""

from __future__ import annotations

import functools
import inspect
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Callable, Mapping, ParamSpec, TypeVar

from millvib_env._checks import shown, shown_path
from millvib_env._paths import config_dir
from millvib_env._yaml import load_yaml
from millvib_env.envs.actions import GainMap
from millvib_env.envs.config import CONFIG_ALIASES, EnvConfig, VersionedConfig
from millvib_env.envs.config import DEFAULT_VERSION

__all__ = ["Task", "get_task", "takes_task", "default_task", "list_tasks", "all_tasks", "SEED_PURPOSES",
           "TASK_ALIASES", "MAX_TRAINING_SEED"]

SEED_PURPOSES = ("training", "tuning", "validation", "heldout")
#: a task's aliases are its config's (``default`` is ``startup``): one table, `envs.config.CONFIG_ALIASES`
TASK_ALIASES = CONFIG_ALIASES
#: training seeds 0..MAX_TRAINING_SEED (100 environment seeds each, evaluation 5000 further on)
MAX_TRAINING_SEED = 49
TRAIN_SEED_STRIDE = 100
EVAL_SEED_OFFSET = 5000


@dataclass(frozen=True)
class Task:
    name: str
    config: str
    description: str
    seeds: dict  # purpose -> range (inclusive bounds in the file, a Python range here)
    #: the task's environment config per environment version (``configs["v1"]``; v0: the paper's analog loop, v1:
    #: the loop as commissioned), each read and validated at its first use and shared: it is frozen
    configs: Mapping[str, EnvConfig] = field(init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "configs", VersionedConfig(self.config))

    def env_config(self, version: str = DEFAULT_VERSION) -> EnvConfig:
        """``configs[version]``, kept for one release for earlier scripts."""
        return self.configs[version]

    def gain_map(self, version: str = DEFAULT_VERSION) -> GainMap:
        """The gain map of the task's gain-schedule action in `version`, kept for one release for earlier scripts:
        ``GainMap.from_config(task.configs[version])``."""
        return GainMap.from_config(self.configs[version])

    def train_env_seed(self, seed: int) -> int:
        """First environment seed of training seed `seed` (environment i uses this + i)."""
        self._check_training_seed(seed)
        return self.seeds["training"].start + TRAIN_SEED_STRIDE * seed

    def eval_env_seed(self, seed: int) -> int:
        self._check_training_seed(seed)
        return self.seeds["training"].start + EVAL_SEED_OFFSET + TRAIN_SEED_STRIDE * seed

    def _check_training_seed(self, seed: int) -> None:
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_TRAINING_SEED:
            raise ValueError(f"training seed {shown(seed)} is invalid: an integer in [0, {MAX_TRAINING_SEED}]")

    def purpose_of(self, seed: int) -> str | None:
        for purpose, rng in self.seeds.items():
            if seed in rng:
                return purpose
        return None

    def heldout_plants(self, n: int, seed: int = 0) -> list[int]:
        """`n` distinct held-out episode seeds (plants) drawn by a generator seeded with `seed`,
        in increasing order: different seeds give mostly different plants, never a shifted range."""
        import numpy as np

        rng_ = self.seeds["heldout"]
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= len(rng_):
            raise ValueError(f"episodes {shown(n)} is invalid: a whole number in [1, {len(rng_)}] (task "
                             f"{shown(self.name)} has {len(rng_)} held-out plants)")
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(f"seed {shown(seed)} is invalid: a whole number >= 0 (it seeds the draw of held-out "
                             "plants)")
        picks = np.random.default_rng(seed).choice(len(rng_), size=n, replace=False)
        plants = sorted(rng_.start + int(i) for i in picks)
        self.check_heldout(plants)
        return plants

    def check_heldout(self, seeds) -> None:
        """Refuse held-out seeds outside the task's held-out range (they may be training plants)."""
        rng = self.seeds["heldout"]
        bad = [s for s in seeds if s not in rng]
        if bad:
            where = self.purpose_of(bad[0]) or "no declared range"
            raise ValueError(f"seed {bad[0]} is not a held-out plant of task {shown(self.name)} (it falls in {where}); "
                             f"held-out seeds are {rng.start}-{rng.stop - 1} (configs/tasks.yaml)")


@lru_cache(maxsize=None)
def _load() -> dict[str, Task]:
    path = config_dir() / "tasks.yaml"
    data = load_yaml(path, "task file")
    if not isinstance(data, dict) or not data:
        raise ValueError(f"task file {shown_path(path)} must map task names to {{config, description, seeds}}")
    tasks: dict[str, Task] = {}
    spans: list[tuple[int, int, str]] = []
    for name, entry in data.items():
        if not isinstance(entry, dict) or not isinstance(entry.get("config"), str):
            raise ValueError(f"task file {shown_path(path)}: {name}.config must name an environment config")
        seeds = entry.get("seeds")
        if not isinstance(seeds, dict) or set(seeds) != set(SEED_PURPOSES):
            raise ValueError(f"task file {shown_path(path)}: {name}.seeds must have exactly {list(SEED_PURPOSES)}")
        ranges = {}
        for purpose in SEED_PURPOSES:
            pair = seeds[purpose]
            if (not isinstance(pair, list) or len(pair) != 2 or not all(isinstance(v, int) and not isinstance(v, bool)
                                                                       for v in pair) or not 0 <= pair[0] <= pair[1]):
                raise ValueError(f"task file {shown_path(path)}: {name}.seeds.{purpose} = {shown(pair)} must be "
                                 "[first, last] integers, 0 <= first <= last")
            ranges[purpose] = range(pair[0], pair[1] + 1)
            spans.append((pair[0], pair[1], f"{name}.{purpose}"))
        tasks[name] = Task(name, entry["config"], str(entry.get("description", "")), ranges)
    spans.sort()
    for (a0, a1, an), (b0, b1, bn) in zip(spans, spans[1:]):
        if b0 <= a1:
            raise ValueError(f"task file {shown_path(path)}: seed ranges {an} [{a0}, {a1}] and {bn} [{b0}, {b1}] "
                             "overlap")
    return tasks


def list_tasks() -> list[str]:
    return list(_load())


def all_tasks() -> list[Task]:
    """Every task, in the file's order."""
    return list(_load().values())


def get_task(name: str | Task) -> Task:
    """The task `name` (``default`` is an alias of ``startup``); a Task as it is. Called where a name enters (the
    CLI, the API's entry points, a file that names a task); below them a `Task` is passed down."""
    if isinstance(name, Task):
        return name
    if not isinstance(name, str):
        raise ValueError(f"task = {shown(name)} is invalid: one of {list_tasks()}")
    name = TASK_ALIASES.get(name, name)
    tasks = _load()
    if name not in tasks:
        raise ValueError(f"task {shown(name)} unknown; available: {list(tasks)}")
    return tasks[name]


def default_task() -> Task:
    """The task of a call that names none: startup (a gap change under load; v0: the paper's 1 mm start)."""
    return get_task("startup")


P = ParamSpec("P")
R = TypeVar("R")


def takes_task(*params: str) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """Marks an entry point of the API whose arguments `params` (default ``task``) may name a task: each name
    becomes its `Task` here, before the body runs (`get_task`; a Task passes as it is, and None where it is the
    parameter's default), so the body and everything it calls take a Task and never look it up again."""
    names = params or ("task",)

    def wrap(fn: Callable[P, R]) -> Callable[P, R]:
        sig = inspect.signature(fn)
        missing = [n for n in names if n not in sig.parameters]
        if missing:
            raise TypeError(f"{fn.__qualname__} has no parameter {shown(missing[0])} to take a task")
        optional = {n for n in names if sig.parameters[n].default is None}

        @functools.wraps(fn)
        def entry(*args: P.args, **kwargs: P.kwargs) -> R:
            try:
                bound = sig.bind(*args, **kwargs)
            except TypeError as err:  # a call that does not fit the signature, named as Python names it
                raise TypeError(f"{fn.__qualname__}() {err}") from None
            bound.apply_defaults()
            for n in names:
                value = bound.arguments[n]
                if not isinstance(value, Task) and not (value is None and n in optional):
                    bound.arguments[n] = get_task(value)
            return fn(*bound.args, **bound.kwargs)

        return entry

    return wrap
