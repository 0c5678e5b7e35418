"""Which controllers a benchmark runs: names and groups ('classical', 'bounds', 'answer', 'on-preview') expanded,
a user's own `Controller` objects checked, the runs (controller x training seed) loaded, and each controller's
information set and preview keywords."""

from __future__ import annotations

import copy
from typing import Any, Mapping, Sequence

from tqdm.auto import tqdm

from millvib_env._checks import shown
from millvib_env.catalog.agents import agent_base, agent_validation_cost, list_agents
from millvib_env.control.base import Controller
from millvib_env.catalog.factory import ControllerSpec, build_controller, resolve_controller
from millvib_env.catalog.information import from_env_kwargs
from millvib_env.catalog.registry import REFERENCE, REGISTRY, ROOM_BOUNDS, baseline_names
from millvib_env.envs.batch import env_id_for, env_version
from millvib_env.tasks import Task
from millvib_env.evaluation.benchmark.protocol import PREVIEW_SETTINGS




#: the group 'answer' (`answer_group`): the classical controller of the students' information and its bound
ANSWER_CLASSICAL, ANSWER_BOUND = "pid-pf-preview", "mpc-preview"
#: the deployable classical controllers, among which the best is named (`Baseline.classical`)
DEPLOYABLE_CLASSICAL = tuple(name for name, b in REGISTRY.items() if b.classical)


def _load_units(names: list[str], task: Task, all_seeds: bool, version: str, progress: bool = False,
                own: Mapping[str, Controller] | None = None,
                here: bool = True) -> tuple[list[tuple[str, int | None]], dict, dict]:
    """The runs of a benchmark, (name, training seed or None for a baseline), their controllers and their specs:
    every agent on its lowest seed, or on every seed it ships (`all_seeds`); a user's `own` controllers as
    they are (no spec: they run in this process). Each name is resolved once (`resolve_controller`); where the runs
    go to workers (`here` False) only each agent's lowest seed is loaded in this process (for its environment and
    the named scenarios): the workers build the seeds they run from their specs."""

    units: list[tuple[str, int | None]] = []
    loaded: dict[tuple, Controller] = {}
    specs: dict[tuple, ControllerSpec] = {}
    for n in tqdm(names, desc=f"benchmark {task.name}: loading", unit="controller", disable=not progress, leave=False):
        if own and n in own:
            units.append((n, None))
            loaded[(n, None)] = _on_task(own[n], task)
            continue
        spec = resolve_controller(n, task, version=version)
        first = build_controller(spec)
        if first.seed is not None:  # a trained policy (an exported graph holds one seed)
            every = spec.kind == "agent" and all_seeds and first.card is not None
            for s in ([sd for sd, _ in spec.paths] if every else [first.seed]):
                units.append((n, s))
                specs[(n, s)] = spec.for_seed(s) if spec.kind == "agent" else spec
                if s == first.seed:
                    loaded[(n, s)] = first
                elif here:
                    loaded[(n, s)] = build_controller(specs[(n, s)])
        else:
            units.append((n, None))
            loaded[(n, None)] = first
            specs[(n, None)] = spec
    return units, loaded, specs


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


def default_lineup(version: str, task: Task) -> list[str]:
    """The controllers of a benchmark that names none: every baseline of `version` and every agent trained on
    `task` in it, but the retired ones (`catalog.agents.agent_retired`: named, they run)."""
    return baseline_names(version) + list_agents(task, version, retired=False)


def answer_group(version: str, task: Task) -> list[str]:
    """The group 'answer', the mission's question in one table: the paper's fixed-gain PID, the reference, and in
    v1 the classical controller of the preview's information (`ANSWER_CLASSICAL`), the best shipped learned
    controller trained on top of it for `task` (their cards' ``on``; the best: the lowest mean validation cost of
    its seeds' cards, `agent_validation_cost`, on the validation plants every one of them was selected on; never
    the held-out plants) and the bound with the same preview (`ANSWER_BOUND`), which gives the room."""
    if ANSWER_CLASSICAL not in baseline_names(version):
        return ["pid-paper", REFERENCE]
    learned = on_preview_group(version, task)
    best = [min(learned, key=agent_validation_cost)] if learned else []
    return ["pid-paper", REFERENCE, ANSWER_CLASSICAL, *best, ANSWER_BOUND]


def on_preview_group(version: str, task: Task) -> list[str]:
    """The group 'on-preview': every shipped learned controller trained on top of `ANSWER_CLASSICAL` for `task`
    (their cards' ``on``), the retired ones left out."""
    return [a for a in list_agents(task, version, retired=False) if agent_base(a) == ANSWER_CLASSICAL]


def _expand_groups(names: Sequence[str], version: str, task: Task) -> list[str]:
    """Controller names with the groups 'classical' (`DEPLOYABLE_CLASSICAL`), 'bounds' (the `ROOM_BOUNDS` that
    the version has), 'answer' (`answer_group`) and 'on-preview' (`on_preview_group`) in place, each name once."""
    have = set(baseline_names(version))
    groups = {"classical": [n for n in DEPLOYABLE_CLASSICAL if n in have],
              "bounds": [n for n in ROOM_BOUNDS if n in have]}
    if "answer" in names:
        groups["answer"] = answer_group(version, task)
    if "on-preview" in names:
        groups["on-preview"] = on_preview_group(version, task)
        if not groups["on-preview"]:
            raise ValueError(f"controllers = 'on-preview' is empty for task {task.name} in {version}: the group is the "
                             f"shipped learned controllers trained on {ANSWER_CLASSICAL}, which runs in v1")
    return list(dict.fromkeys(m for n in names for m in groups.get(n, [n])))


def information_of(name: str, ctrl: Controller, task: Task, version: str) -> str:
    """What controller `name` reads (`catalog.information`): a baseline's declared set, else the set its
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
    (a student that learned on the measured preview runs on the exact one under ``--preview exact``; `preview` one
    of `PREVIEW_GAUGES`, given as `PREVIEW_SETTINGS` says)."""
    return {n: {"observation": {"preview_gauge": PREVIEW_SETTINGS[preview]}} for n, c in ctrls.items()
            if _reads_preview(c)}
