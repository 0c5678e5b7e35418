"""The registered environments, in one table: every id with its engine mode, version, config and entry points.

Gymnasium's registration (`millvib_env._register_envs`), the batched engine and SB3 VecEnv (`envs.batch`,
`envs.vec_env`) and the training CLI's id checks all read `ENV_SPECS`; an id is never taken apart as a string.
"""

from __future__ import annotations

from dataclasses import dataclass

from millvib_env.envs.config import ENV_VERSIONS, cached_env_config

__all__ = ["EnvSpec", "ENV_SPECS", "MODES", "TASK_CONFIGS"]

#: the environments' names and the batched engine's mode of each
MODES = {"GainSchedule": "gain", "Valve": "valve"}
#: the env configs that have an id of their own (the tasks' configs), for clients that take an id string only
TASK_CONFIGS = ("startup", "rolling", "change", "varied")


@dataclass(frozen=True)
class EnvSpec:
    """One registered id: ``MillVib-<name>-<version>`` (generic: config `startup` unless one is passed) or
    ``MillVib-<name>-<Config>-<version>`` (that config only)."""

    id: str
    name: str           # GainSchedule or Valve
    mode: str           # the batched engine's mode: gain or valve
    version: str        # v0: the paper's analog loop; v1: the loop as commissioned
    config: str | None  # the id's own env config; None for a generic id

    @property
    def entry_point(self) -> str:
        """Gymnasium's entry point (`_entry`: named gain sets resolved, then `envs.environments`)."""
        return f"millvib_env._entry:{self.name}Env"

    @property
    def vector_entry_point(self) -> str:
        """Gymnasium's vector entry point: the batched engine as a `gymnasium.vector.VectorEnv`."""
        return f"millvib_env._entry:{self.name}VectorEnv"

    @property
    def max_episode_steps(self) -> int | None:
        """The steps of the id's episode, for a per-task id (its config's episode_s over the step's period): Gymnasium
        wraps its TimeLimit there, where the environment truncates anyway. None for a generic id, which takes any
        config and episode length (a TimeLimit at one task's length would cut another's episodes): its
        environments end their episodes themselves."""
        if self.config is None:
            return None
        return cached_env_config(self.config, self.version).episode_steps(self.mode)

    @property
    def kwargs(self) -> dict:
        """The keyword arguments the id registers with (a per-task id's `max_episode_steps` too: its entry point
        refuses settings whose episode would run past it)."""
        return {"env_version": self.version} if self.config is None else \
            {"env_version": self.version, "config": self.config, "max_episode_steps": self.max_episode_steps}

    @property
    def generic_id(self) -> str:
        """The generic id of the same environment and version."""
        return f"MillVib-{self.name}-{self.version}"


def _specs() -> dict[str, EnvSpec]:
    specs = {}
    for name, mode in MODES.items():
        for version in ENV_VERSIONS:
            for config in (None, *TASK_CONFIGS):  # the generic id first, then one per task config
                env_id = f"MillVib-{name}-{version}" if config is None else \
                    f"MillVib-{name}-{config.capitalize()}-{version}"
                specs[env_id] = EnvSpec(env_id, name, mode, version, config)
    return specs


#: every registered id -> its spec
ENV_SPECS: dict[str, EnvSpec] = _specs()
