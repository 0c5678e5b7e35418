"""Named gain sets: a hyperparameter file, a model card or ``gym.make``'s keyword arguments may name a fixed-gain
baseline where the env takes gains (``actions: {residual_gains: pid-pf-ff}``, ``relative: {base: pid-pf-robust}``).
The name is resolved here, in the control layer, to that baseline's gains on the task whose config the keyword
arguments name (startup for any other config) in the environment's version; the env layer takes numbers only.

`resolve_named_gains` is applied where keyword arguments enter: the registered env ids' entry points
(`millvib_env._entry`), `millvib_env.make_vec_env`, an agent's card (`catalog.agents.AgentPolicy`), `train` and
`distill`.
"""

from __future__ import annotations

from typing import Any, Mapping

from millvib_env._checks import shown
from millvib_env.catalog.registry import REGISTRY
from millvib_env.envs.config import CONFIG_ALIASES
from millvib_env.tasks import Task, all_tasks, takes_task
from millvib_env.envs.config import DEFAULT_VERSION

__all__ = ["NAMED_GAINS", "named_gains", "task_of_config", "has_named_gains", "resolve_named_gains",
           "resolve_named_gains_for"]

#: the fixed-gain baselines whose gains may be named (`catalog.registry.Baseline.fixed`)
NAMED_GAINS: tuple[str, ...] = tuple(name for name, b in REGISTRY.items() if b.named_gains)


def named_gains(name: str, task: Task, version: str = DEFAULT_VERSION) -> list[float]:
    """The gains of the fixed-gain baseline `name` of `task` in environment version `version`:
    its control config entry (`catalog.tuned.control_entry`, which follows ``from_task``), checked
    (`catalog.tuned.entry_gains`); the paper's PID from MillParams' module."""

    gains_fn = REGISTRY[name].gains if name in REGISTRY else None
    if gains_fn is None:
        raise ValueError(f"gains {shown(name)} unknown: name a fixed-gain baseline {list(NAMED_GAINS)}")
    return gains_fn(name, task, version)[0]


def task_of_config(config: Any) -> Task:
    """The task whose environment config `config` names (startup for any other config)."""
    tasks = all_tasks()
    if isinstance(config, str):
        name = CONFIG_ALIASES.get(config, config)
        for t in tasks:
            if t.config == name:
                return t
    for t in tasks:
        if t.name == "startup":
            return t
    raise ValueError("configs/tasks.yaml has no task 'startup', the task of a config that names none")


def _resolve_actions(acts: Any, task: Task, version: str) -> Any:
    """An ``actions`` section with its named gain sets replaced by numbers (a new dict; anything else as given,
    for the env's own checks to refuse)."""
    if not isinstance(acts, Mapping):
        return acts
    acts = dict(acts)
    if isinstance(acts.get("residual_gains"), str):
        acts["residual_gains"] = named_gains(acts["residual_gains"], task, version)
    rel = acts.get("relative")
    if isinstance(rel, Mapping) and isinstance(rel.get("base"), str):
        acts["relative"] = {**rel, "base": named_gains(rel["base"], task, version)}
    return acts


def has_named_gains(env_kwargs: Mapping) -> bool:
    """Whether keyword arguments name a gain set anywhere `resolve_named_gains` looks (cheap: no import)."""
    sections = [env_kwargs.get("actions")]
    if isinstance(env_kwargs.get("config"), Mapping):
        sections.append(env_kwargs["config"].get("actions"))
    for acts in sections:
        if isinstance(acts, Mapping):
            rel = acts.get("relative")
            if isinstance(acts.get("residual_gains"), str) or (isinstance(rel, Mapping) and
                                                                isinstance(rel.get("base"), str)):
                return True
    return False


@takes_task()
def resolve_named_gains(env_kwargs: Mapping, task: str | Task | None = None, version: str | None = None) -> dict:
    """`env_kwargs` (an env's keyword arguments, a card's or a hyperparameter file's ``env_kwargs``) with every
    named gain set replaced by that baseline's gains: in ``actions`` and in a mapping ``config``'s ``actions``.
    `task` defaults to the task whose config ``env_kwargs["config"]`` names, `version` to
    ``env_kwargs["env_version"]`` (else `DEFAULT_VERSION`, v1). Returns a new dict; `env_kwargs` is left as it was."""
    if not has_named_gains(env_kwargs):
        return dict(env_kwargs)
    assert task is None or isinstance(task, Task)  # a name was resolved by @takes_task
    t = task or task_of_config(env_kwargs.get("config"))
    return resolve_named_gains_for(env_kwargs, t, version)


def resolve_named_gains_for(env_kwargs: Mapping, task: Task, version: str | None = None) -> dict:
    """`resolve_named_gains` for a resolved `Task` (callers below the entry points); `version` defaults to
    ``env_kwargs["env_version"]``, else `DEFAULT_VERSION`."""
    out = dict(env_kwargs)
    if not has_named_gains(out):
        return out
    t = task
    version = version if version is not None else str(out.get("env_version") or DEFAULT_VERSION)
    if "actions" in out:
        out["actions"] = _resolve_actions(out["actions"], t, version)
    if isinstance(out.get("config"), Mapping) and "actions" in out["config"]:
        out["config"] = {**out["config"], "actions": _resolve_actions(out["config"]["actions"], t, version)}
    return out
