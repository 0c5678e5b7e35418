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
    """Register the ids of `envs.specs.ENV_SPECS`: two environments in two versions (v0: the paper's analog loop;
    v1: the loop as commissioned), each as a generic id and as one id per task config (MillVib-Valve-Rolling-v1)
    for clients that take an id string only; `gym.make_vec(..., vectorization_mode="vector_entry_point")` gets the
    batched engine. The environments truncate their episodes themselves (after the config's episode_s). A per-task
    id carries its task's episode length as ``max_episode_steps`` (Gymnasium's TimeLimit at the step where the
    environment truncates anyway); a generic id carries none, since one would cut a 1 s `rolling` episode at the
    0.5 s `startup` length."""
    import gymnasium

    from millvib_env.envs.specs import ENV_SPECS

    for env_id, spec in ENV_SPECS.items():
        if env_id not in gymnasium.registry:
            try:
                kwargs, steps = spec.kwargs, spec.max_episode_steps
            except (ValueError, OSError):  # the task's config cannot be read: `gym.make` says why, the import works
                kwargs, steps = {"env_version": spec.version, "config": spec.config}, None
            gymnasium.register(id=env_id, entry_point=spec.entry_point, vector_entry_point=spec.vector_entry_point,
                               kwargs=kwargs, max_episode_steps=steps)


_register_envs()


def make_vec_env(env_id: str, n_envs: int = 1, seed: int | None = None, **env_kwargs):
    """Native batched Stable-Baselines3 VecEnv (see `millvib_env.envs.vec_env.make_vec_env`)."""
    from millvib_env.catalog.named import resolve_named_gains
    from millvib_env.envs.batch import env_version
    from millvib_env.envs.vec_env import make_vec_env as _make

    return _make(env_id, n_envs, seed, **resolve_named_gains(env_kwargs, version=env_version(env_id)))


__all__ += ["make_vec_env"]
