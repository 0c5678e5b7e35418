"""millvib-env: hydraulic screw-down vibration of a rolling mill, as a simulator and RL environments."""
from millvib_env import _numba_cache

_numba_cache.configure()  # before any numba import: cache keyed by this package's source

# isort: split
from millvib_env.params import PAPER_GAINS, MillParams, PIDGains, load_preset

__version__ = "0.1.0"
__all__ = ["MillParams", "PIDGains", "PAPER_GAINS", "load_preset", "__version__"]


def _register_envs() -> None:
    import gymnasium

    from millvib_env.envs.config import load_env_config

    default = load_env_config("default")
    steps = {"gain": round(default.episode_s / default.decision_dt_s),
             "valve": round(default.episode_s / default.control_dt_s)}
    for env_id, entry, mode in (("MillVib-GainSchedule-v0", "millvib_env.envs.base:GainScheduleEnv", "gain"),
                                ("MillVib-Valve-v0", "millvib_env.envs.base:ValveEnv", "valve")):
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry, max_episode_steps=steps[mode])


_register_envs()


def make_vec_env(env_id: str, n_envs: int = 1, seed: int | None = None, **env_kwargs):
    """Native batched Stable-Baselines3 VecEnv (see `millvib_env.envs.vec_env.make_vec_env`)."""
    from millvib_env.envs.vec_env import make_vec_env as _make

    return _make(env_id, n_envs, seed, **env_kwargs)


__all__ += ["make_vec_env"]
