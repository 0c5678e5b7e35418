"""The tuned baselines' config files, configs/control/[<version>/]<task>.yaml: the entry of a baseline (following
`from_task`), its gains and its oracle tables, each checked as data before use. Every reader takes the `Task`
(resolved where the name entered); `load_control_config` also takes a name."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from millvib_env._checks import choice, shown, shown_path
from millvib_env._paths import config_dir
from millvib_env._yaml import load_yaml
from millvib_env.control.base import GainTable
from millvib_env.envs.config import ENV_VERSIONS
from millvib_env.envs.schema import checked_gains
from millvib_env.tasks import Task, get_task, takes_task
from millvib_env.envs.config import DEFAULT_VERSION

__all__ = ["control_config_path", "load_control_config", "control_entry", "shared_from", "entry_gains",
           "oracle_table"]


def control_config_path(task: Task, version: str = DEFAULT_VERSION) -> Path:
    """Where a task's tuned baselines live: configs/control/<task>.yaml for v0 (the analog loop),
    configs/control/<version>/<task>.yaml for a later version (v1: the loop as commissioned)."""
    folder = config_dir() / "control"
    return (folder if version == "v0" else folder / version) / f"{task.name}.yaml"


@takes_task()
def load_control_config(task: str | Task, version: str = DEFAULT_VERSION) -> dict[str, Any]:
    """The task's tuned baselines in environment version `version` (an entry may say `from_task: NAME`)."""
    assert isinstance(task, Task)  # a name was resolved by @takes_task
    return _read(task, choice("version", version, ENV_VERSIONS))


def _read(task: Task, version: str) -> dict[str, Any]:
    path = control_config_path(task, version)
    if not path.is_file():
        raise ValueError(f"no tuned baselines for task {shown(task.name)} in {version}: {shown_path(path)} is "
                         f"missing (run millvib tune --task {task.name} --env-version {version} --write-config)")
    return load_yaml(path, "control config", mapping=True)


def control_entry(task: Task, name: str, version: str = DEFAULT_VERSION, _via: tuple = ()) -> dict:
    """Entry `name` of the task's control config, following `from_task` (a cycle is refused in one line)."""
    if task.name in _via:
        raise ValueError(f"{control_config_path(task, version)} {name}: from_task runs in a cycle "
                         f"({' -> '.join(_via + (task.name,))}); one of them must hold the entry itself")
    data = _read(task, version)
    if name not in data:
        raise ValueError(f"{control_config_path(task, version)} has no entry {shown(name)} (run millvib tune --task "
                         f"{task.name} --env-version {version} --only {name} --write-config)")
    entry = data[name]
    source = shared_from(entry, f"{control_config_path(task, version)} {name}")
    if source is not None:
        return control_entry(source, name, version, _via + (task.name,))
    return entry


def shared_from(entry: Any, where: str) -> Task | None:
    """The task whose entry an entry shares (``from_task: NAME``, as `millvib tune --from-task` writes it), or None
    for an entry of its own: the one place where a config file's task name becomes a Task."""
    if not isinstance(entry, dict) or "from_task" not in entry:
        return None
    if not isinstance(entry["from_task"], str):
        raise ValueError(f"{where}.from_task = {shown(entry['from_task'])} is invalid: a task name")
    return get_task(entry["from_task"])


def entry_gains(task: Task, name: str, entry: dict, version: str = DEFAULT_VERSION) -> list[float]:
    """A fixed-gain entry's gains, checked (`envs.config.checked_gains`): 3-5 finite numbers >= 0."""
    return checked_gains(entry.get("gains") if isinstance(entry, dict) else None,
                         f"{control_config_path(task, version)} {name}.gains",
                         f"run millvib tune --task {task.name} --env-version {version} --only {name} "
                         "--write-config")


def oracle_table(task: Task, name: str = "pid-oracle", version: str = DEFAULT_VERSION) -> GainTable:
    """The gain table of oracle `name`, checked as data: positive increasing grids of finite numbers and finite
    log10 gains of shape (len(c1_grid), len(ct_grid), 3-5), gains within 1e-12 to 1e15."""
    entry = control_entry(task, name, version)
    where = f"{control_config_path(task, version)} {name}"
    if not isinstance(entry, dict):
        raise ValueError(f"{where} = {shown(entry)} is invalid: a mapping with c1_grid, ct_grid and log10_gains")
    grids = []
    for key in ("c1_grid", "ct_grid"):
        try:
            g = np.asarray(entry.get(key), dtype=float)
        except (TypeError, ValueError, OverflowError):
            g = np.zeros(0)
        if g.ndim != 1 or g.size < 2 or not np.all(np.isfinite(g)) or np.any(g <= 0) or np.any(np.diff(g) <= 0):
            raise ValueError(f"{where}.{key} = {entry.get(key)!r:.60} is invalid: at least 2 increasing finite "
                             "numbers > 0")
        grids.append(g)
    try:
        table = np.asarray(entry.get("log10_gains"), dtype=float)
    except (TypeError, ValueError, OverflowError):
        table = np.zeros(0)
    if table.shape[:2] != (grids[0].size, grids[1].size) or table.ndim != 3 or not 3 <= table.shape[2] <= 5 \
            or not np.all(np.isfinite(table)) or np.any(np.abs(table) > 15):
        raise ValueError(f"{where}.log10_gains is invalid: finite log10 gains in [-15, 15] of shape "
                         f"({grids[0].size}, {grids[1].size}, 3-5), one row per grid plant")
    return GainTable(grids[0], grids[1], table)
