"""Controllers by name: `load_controller` builds a baseline through its registry entry (`catalog.registry`,
from its tuned entry in configs/control/[v1/]<task>.yaml, `catalog.tuned`) or loads a trained agent
(`catalog.agents`), so every command and the plain Gymnasium loop (`ctrl.make_env()`) get the same controller
for the same name.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from millvib_env._checks import instance, shown, shown_path
from millvib_env.catalog.agents import AgentPolicy, agent_folder, agent_seed_folders
from millvib_env.control.base import Controller
from millvib_env.catalog.onnx_policy import OnnxPolicy, is_onnx_name
from millvib_env.catalog.registry import REGISTRY, baseline_names
from millvib_env.catalog.tuned import control_config_path, control_entry, load_control_config, oracle_table
from millvib_env.envs.actions import GainMap
from millvib_env.envs.batch import env_id_for
from millvib_env.envs.config import ENV_VERSIONS, EnvConfig
from millvib_env.tasks import Task, default_task, takes_task
from millvib_env.envs.config import DEFAULT_VERSION

__all__ = ["load_controller", "load_control_config", "control_entry", "control_config_path", "oracle_table",
           "ControllerSpec", "resolve_controller", "build_controller"]


@dataclass(frozen=True)
class ControllerSpec:
    """A controller as `resolve_controller` found it by name: what `build_controller` makes it from without looking
    the name up again (a benchmark resolves each name once in its own process and hands its workers specs).

    kind: "baseline" (its registry entry), "agent" (a shipped or saved agent: `paths` holds each training seed's
    folder, `seed` the one to build) or "graph" (an exported ONNX file: `paths` holds it)."""

    name: str
    kind: str
    task: Task | None
    version: str
    seed: int | None = None
    paths: tuple = ()

    def for_seed(self, seed: int) -> ControllerSpec:
        """The same agent on training seed `seed` (one it ships)."""
        seeds = dict(self.paths)
        if self.kind != "agent" or seed not in seeds:
            raise ValueError(f"agent {shown(self.name)} has no training seed {seed}: it ships seeds {list(seeds)}")
        return replace(self, seed=seed)


def resolve_controller(name: str, task: Task | None = None, seed: int | None = None,
                       version: str = DEFAULT_VERSION) -> ControllerSpec:
    """`name` resolved once (`load_controller`'s lookup, nothing loaded): a baseline, a shipped agent or an agent
    folder (its training seed `seed`, default its lowest) or an exported graph; `task` a Task or None."""
    if version not in ENV_VERSIONS:
        raise ValueError(f"version = {shown(version)} is invalid: one of {list(ENV_VERSIONS)}")
    if not isinstance(name, str) or not name:
        raise ValueError(f"controller {shown(name)} is invalid: a baseline {baseline_names()} or an agent name or path")
    if task is not None and not isinstance(task, Task):
        raise ValueError(f"task = {shown(task)} is invalid: a Task (tasks.get_task) or None")
    if name in REGISTRY:
        return ControllerSpec(name, "baseline", task if task is not None else default_task(), version)
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
        raise ValueError(f"seed = {shown(seed)} is invalid: a training seed (an integer) or None for the lowest")
    if is_onnx_name(name):
        return ControllerSpec(name, "graph", task, version, seed, (name,))
    seeds = agent_seed_folders(agent_folder(name))
    spec = ControllerSpec(name, "agent", task, version, next(iter(seeds)), tuple(seeds.items()))
    return spec if seed is None else spec.for_seed(int(seed))


def build_controller(spec: ControllerSpec, config: EnvConfig | None = None) -> Controller:
    """The controller `spec` names (`resolve_controller`); a baseline's environment config `config` (default its
    task's, in its version)."""
    instance("spec", spec, ControllerSpec, "a ControllerSpec (resolve_controller)")
    if spec.kind == "graph":
        return _exported(spec.paths[0], spec.task, spec.seed)
    if spec.kind == "agent":
        return _on_task(AgentPolicy(dict(spec.paths)[spec.seed]), spec.name, spec.task)
    t = spec.task if spec.task is not None else default_task()
    gain_map = GainMap.from_config(config if config is not None else t.configs["v0"])
    entry = REGISTRY[spec.name]
    ctrl = entry.build(spec.name, t, spec.version, config or t.configs[spec.version], gain_map)
    ctrl.task = t
    ctrl.env_id = env_id_for(entry.env_mode, spec.version)
    return ctrl


@takes_task()
def load_controller(name: str, task: str | Task | None = None, config: EnvConfig | None = None,
                    seed: int | None = None, version: str = DEFAULT_VERSION) -> Controller:
    """A controller by name for `task`: a baseline (`catalog.registry.REGISTRY`), a shipped agent (agents/<name>),
    an agent folder path or an exported agent's ONNX graph (``*.onnx``, `catalog.onnx_policy`: no torch). `seed`
    picks a training seed of a multi-seed agent (default: its lowest; a graph holds one).
    `task` defaults to the agent's own (startup for a baseline); an agent trained on another task
    than the one asked for is refused. A baseline runs in environment version `version` with the gains
    tuned for it (`control_config_path`); an agent runs in the version it was trained in. The same as
    `build_controller(resolve_controller(name, task, seed, version), config)`."""
    if config is not None and not isinstance(config, EnvConfig):
        raise ValueError(f"config = {shown(config)} is invalid: None or an EnvConfig (envs.config.load_env_config)")
    assert task is None or isinstance(task, Task)  # a name was resolved by @takes_task; None: an agent's own task
    return build_controller(resolve_controller(name, task, seed, version), config)


def _on_task(agent: AgentPolicy | OnnxPolicy, name: str, task: Task | None):
    """`agent`, where `task` is None or the one it was trained on."""
    if task is not None and task.name != agent.task.name:
        raise ValueError(f"agent {shown(name)} was trained on task {shown(agent.task.name)}, not {shown(task.name)}: "
                         f"run it with task {shown(agent.task.name)}")
    return agent


def _exported(path: str, task: Task | None, seed: int | None) -> OnnxPolicy:
    """An exported agent's graph (`OnnxPolicy`); it holds one training seed, the one exported."""
    policy = OnnxPolicy(path)
    if seed is not None and seed != policy.seed:
        raise ValueError(f"{shown_path(path)} holds training seed {policy.seed} of agent {shown(policy.agent)}, not "
                         f"seed {seed}")
    return _on_task(policy, path, task)
