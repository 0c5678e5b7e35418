"""Controllers by name: `load_controller` builds a baseline from its tuned entry in
configs/control/<task>.yaml (`control.policies`) or loads a trained agent (`control.agents`), so every
command and the plain Gymnasium loop (`ctrl.make_env()`) get the same controller for the same name.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from millvib_env._yaml import load_yaml
from millvib_env.control.agents import AgentPolicy, agent_folder, agent_seed_folders
from millvib_env.control.base import Controller, GainTable
from millvib_env.control.policies import BASELINES, FixedGainPolicy, LQRPolicy, OraclePolicy, baseline_names
from millvib_env.envs.actions import GainMap, task_gain_map
from millvib_env.envs.batch import env_id_for
from millvib_env.envs.config import ENV_VERSIONS, EnvConfig, task_config
from millvib_env.envs.config import control_config_path as _config_path
from millvib_env.params import PAPER_GAINS
from millvib_env.tasks import get_task

__all__ = ["load_controller", "load_control_config", "control_entry", "control_config_path", "oracle_table"]


def control_config_path(task: str, version: str = "v0"):
    """Where a task's tuned baselines live (`envs.config.control_config_path`), for a task name or alias."""
    return _config_path(get_task(task).name, version)


def load_control_config(task: str = "startup", version: str = "v0") -> dict[str, Any]:
    """The task's tuned baselines in environment version `version` (an entry may say `from_task: NAME`)."""
    path = control_config_path(task, version)
    if not path.is_file():
        raise ValueError(f"no tuned baselines for task {get_task(task).name!r} in {version}: {path} is missing (run "
                         f"millvib tune --task {get_task(task).name} --env-version {version} --write-config)")
    return load_yaml(path, "control config", mapping=True)


def control_entry(task: str, name: str, version: str = "v0", _via: tuple = ()) -> dict:
    """Entry `name` of the task's control config, following `from_task` (a cycle is refused in one line)."""
    task = get_task(task).name
    if task in _via:
        raise ValueError(f"{control_config_path(task, version)} {name}: from_task runs in a cycle "
                         f"({' -> '.join(_via + (task,))}); one of them must hold the entry itself")
    data = load_control_config(task, version)
    if name not in data:
        raise ValueError(f"{control_config_path(task, version)} has no entry {name!r} (run millvib tune --task "
                         f"{task} --env-version {version} --only {name} --write-config)")
    entry = data[name]
    if isinstance(entry, dict) and "from_task" in entry:
        if not isinstance(entry["from_task"], str):
            raise ValueError(f"{control_config_path(task, version)} {name}.from_task = {entry['from_task']!r:.60} "
                             "is invalid: a task name")
        return control_entry(entry["from_task"], name, version, _via + (task,))
    return entry


def _checked_gains(task: str, name: str, entry: dict) -> list[float]:
    """An entry's gains (`envs.config.checked_gains`)."""
    from millvib_env.envs.config import checked_gains

    return checked_gains(entry.get("gains") if isinstance(entry, dict) else None,
                         f"configs/control/{get_task(task).name}.yaml {name}.gains")


def oracle_table(task: str, name: str = "pid-oracle", version: str = "v0") -> GainTable:
    """The gain table of oracle `name`, checked as data: positive increasing grids of finite numbers and finite
    log10 gains of shape (len(c1_grid), len(ct_grid), 3-5), gains within 1e-12 to 1e15."""
    entry = control_entry(task, name, version)
    where = f"{control_config_path(task, version)} {name}"
    if not isinstance(entry, dict):
        raise ValueError(f"{where} = {entry!r:.60} is invalid: a mapping with c1_grid, ct_grid and log10_gains")
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


def _mpc(name: str, task: str, version: str) -> Controller:
    """`mpc-oracle` / `mpc-preview` with the task's settings (`control.mpc`)."""
    from millvib_env.control.mpc import MPCPolicy, MPCSettings

    if version == "v0":
        raise ValueError(f"{name} runs on the loop as commissioned: use environment version v1, not v0")
    entry = control_entry(task, name, version)
    settings = entry.get("settings") if isinstance(entry, dict) else None
    if not isinstance(settings, dict):
        raise ValueError(f"{control_config_path(task, version)} {name}.settings = {settings!r:.60} is invalid: "
                         "a mapping of MPCSettings fields")
    fields = [f for f in MPCSettings.__dataclass_fields__ if f != "preview"]
    unknown = sorted(str(k) for k in settings if k not in fields)
    if unknown:
        raise ValueError(f"{control_config_path(task, version)} {name}.settings has unknown keys {unknown}: "
                         f"allowed {fields}")
    ctrl = MPCPolicy(name, MPCSettings(**{**settings, "preview": name == "mpc-preview"}), version)
    ctrl.task = task
    return ctrl


def load_controller(name: str, task: str | None = None, config: EnvConfig | None = None,
                    seed: int | None = None, version: str = "v0") -> Controller:
    """A controller by name for `task`: a baseline (`BASELINES`), a shipped agent (agents/<name>) or
    an agent folder path. `seed` picks a training seed of a multi-seed agent (default: its lowest).
    `task` defaults to the agent's own (startup for a baseline); an agent trained on another task
    than the one asked for is refused. A baseline runs in environment version `version` with the gains
    tuned for it (`control_config_path`); an agent runs in the version it was trained in."""
    if version not in ENV_VERSIONS:
        raise ValueError(f"version = {version!r} is invalid: one of {list(ENV_VERSIONS)}")
    if not isinstance(name, str) or not name:
        raise ValueError(f"controller {name!r} is invalid: a baseline {baseline_names()} or an agent name or path")
    if config is not None and not isinstance(config, EnvConfig):
        raise ValueError(f"config = {config!r:.60} is invalid: None or an EnvConfig (envs.config.load_env_config)")
    if name not in BASELINES:
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
            raise ValueError(f"seed = {seed!r} is invalid: a training seed (an integer) or None for the lowest")
        seeds = agent_seed_folders(agent_folder(name))
        if seed is None:
            seed = next(iter(seeds))
        if seed not in seeds:
            raise ValueError(f"agent {name!r} has no training seed {seed}: it ships seeds {list(seeds)}")
        agent = AgentPolicy(seeds[seed])
        if task is not None and get_task(task).name != agent.task:
            raise ValueError(f"agent {name!r} was trained on task {agent.task!r}, not {get_task(task).name!r}: "
                             f"run it with task {agent.task!r}")
        return agent
    task = get_task(task if task is not None else "startup").name
    gain_map = GainMap.from_config(config) if config is not None else task_gain_map(task)
    cfg = config or task_config(task, version)
    ctrl: Controller
    if name == "pid-paper":
        ctrl = FixedGainPolicy(name, PAPER_GAINS, gain_map, BASELINES[name])
    elif name in ("pid-nominal", "pid-robust", "pid-pf-robust", "pid-pf-ff"):
        entry = control_entry(task, name, version)
        ctrl = FixedGainPolicy(name, _checked_gains(task, name, entry), gain_map, entry.get("how", ""))
    elif name in ("pid-oracle", "pid-pf-oracle"):
        ctrl = OraclePolicy(oracle_table(task, name, version), gain_map, name, task)
    elif name == "lqr-oracle":
        from millvib_env.control.lqr import LQRWeights

        entry = control_entry(task, name, version)
        ctrl = LQRPolicy(LQRWeights(**entry["weights"]), cfg.base_params, task, loop=cfg.loop)
    elif name in ("mpc-oracle", "mpc-preview"):
        return _mpc(name, task, version)
    elif name == "pid-adaptive":
        from millvib_env.control.adaptive import AdaptivePolicy, EstimatorSettings

        entry = control_entry(task, name, version)
        ctrl = AdaptivePolicy(oracle_table(task, version=version), gain_map, EstimatorSettings(**entry["estimator"]),
                              cfg.base_params, sample_rate_hz=cfg.sample_rate_hz)
    ctrl.task = task
    ctrl.env_id = env_id_for("gain", version)
    return ctrl
