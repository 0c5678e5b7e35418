"""millvib-env: hydraulic screw-down vibration of a rolling mill, as a simulator and RL environments."""
from millvib_env import _numba_cache, threads

_numba_cache.configure()  # before any numba import: cache keyed by this package's source
threads.passive_waiting()  # before numba's OpenMP pool starts: idle threads sleep, not spin

# isort: split
from millvib_env.params import PAPER_GAINS, MillParams, PIDGains, load_preset  # noqa: E402 (after the two calls)

try:  # one home for the version: pyproject.toml, read from the installed package's metadata
    from importlib.metadata import PackageNotFoundError, version as _version

    __version__ = _version("millvib-env")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
__all__ = ["MillParams", "PIDGains", "PAPER_GAINS", "load_preset", "__version__"]


def _register_envs() -> None:
    """Register the ids: two environments in two versions (v0: the paper's analog loop; v1: the loop as
    commissioned). The environments truncate their episodes themselves (after the config's episode_s),
    so no TimeLimit is registered: one would cut a 1 s `rolling` episode at the 0.5 s `startup` length."""
    import gymnasium

    for name in ("GainSchedule", "Valve"):
        for version in ("v0", "v1"):
            # the generic id, then one per task config (MillVib-Valve-Rolling-v1: config="rolling") for clients
            # that take an id string only; the same list as envs.batch.ID_CONFIGS (tested)
            for config in (None, "startup", "rolling", "change", "varied"):
                env_id = f"MillVib-{name}-{version}" if config is None else \
                    f"MillVib-{name}-{config.capitalize()}-{version}"
                kwargs = {"env_version": version} if config is None else {"env_version": version, "config": config}
                if env_id not in gymnasium.registry:  # gym.make_vec(..., vectorization_mode="vector_entry_point"):
                    gymnasium.register(id=env_id, entry_point=f"millvib_env._entry:{name}Env",  # the batched
                                       vector_entry_point=f"millvib_env._entry:{name}VectorEnv",  # engine
                                       kwargs=kwargs)  # (_entry: named gain sets resolved, then envs.base / vector)


_register_envs()


def make_vec_env(env_id: str, n_envs: int = 1, seed: int | None = None, **env_kwargs):
    """Native batched Stable-Baselines3 VecEnv (see `millvib_env.envs.vec_env.make_vec_env`)."""
    from millvib_env.control.named import resolve_named_gains
    from millvib_env.envs.batch import env_version
    from millvib_env.envs.vec_env import make_vec_env as _make

    return _make(env_id, n_envs, seed, **resolve_named_gains(env_kwargs, version=env_version(env_id)))


__all__ += ["make_vec_env"]
