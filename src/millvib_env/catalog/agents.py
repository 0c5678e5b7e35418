"""Trained agents and their folders: what an agent folder holds (card.json, model.zip,
vecnormalize.npz, evaluations.npz; `catalog.manifest` checks the shipped ones, `catalog.normalization`
reads the statistics), how a name finds one (a shipped agent under agents/ always wins; a local folder
needs a path) and `AgentPolicy`, which runs one with SB3's `predict`.
"""

from __future__ import annotations

import importlib.util
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from millvib_env import _jax_cache
from millvib_env._checks import shown, shown_path
from millvib_env._paths import agents_dir
from millvib_env.control.base import Controller
from millvib_env.catalog.manifest import verify_agent
from millvib_env.catalog.named import resolve_named_gains_for
from millvib_env.catalog.normalization import STATS_FILE, ObsStats, load_obs_stats, normalizes_obs
from millvib_env.catalog.registry import baseline_names
from millvib_env.catalog.sbx_to_sb3 import sb3_sac_from_sbx
from millvib_env.envs.batch import env_version
from millvib_env.tasks import Task, get_task, takes_task
from millvib_env.threads import one_torch_thread, one_xla_thread

__all__ = ["AgentPolicy", "ALGOS", "BACKENDS", "Learner", "learner", "algo_class", "resolved_backend",
           "deterministic_actor", "agent_env_kwargs", "AGENT_ENV_KEYS", "SEED_FOLDER", "agent_seed_folders",
           "list_agents", "agent_retired", "agent_folder", "agent_seeds"]


#: the algorithms an agent may be trained with (`millvib train --algo`)
ALGOS = ("ppo", "sac", "recurrentppo")
#: the learner libraries (`millvib train --backend`): Stable-Baselines3 (PyTorch, the default) and sbx,
#: its JAX port (`pip install -e '.[sbx]'`), for PPO and SAC; a model card records its backend
BACKENDS = {"sb3": ALGOS, "sbx": ("ppo", "sac")}


def resolved_backend(algo: str, backend: str = "auto") -> str:
    """The learner library `millvib train` uses: `backend` as given, or for "auto" (the default) sbx for SAC where
    it is installed (about twice SB3's speed, docs/performance.md) and SB3 otherwise. A SAC trained with sbx is
    saved in SB3's format (`catalog.sbx_to_sb3`), so it loads, runs and exports without JAX."""
    if backend == "auto":
        return "sbx" if str(algo).lower() == "sac" and importlib.util.find_spec("sbx") is not None else "sb3"
    return backend


def algo_class(algo: str, backend: str = "sb3"):
    """The learner class of an algorithm name for a backend (SB3, sb3-contrib or sbx); imported only
    when asked for."""
    if backend not in BACKENDS:
        raise ValueError(f"backend = {shown(backend)} is invalid: one of {sorted(BACKENDS)}")
    if algo not in BACKENDS[backend]:
        raise ValueError(f"algo = {shown(algo)} is invalid for backend {shown(backend)}: one of {BACKENDS[backend]}")
    if backend == "sbx":

        one_xla_thread()  # before JAX starts (training or loading): its thread pool would take every core
        _jax_cache.configure()  # and its compilations kept on disk: the next start loads them
        try:
            import sbx
        except ImportError:
            raise ValueError("backend 'sbx' needs sbx-rl and JAX: pip install -e '.[sbx]'") from None
        return {"ppo": sbx.PPO, "sac": sbx.SAC}[algo]
    if algo == "ppo":
        from stable_baselines3 import PPO
        return PPO
    if algo == "sac":
        from stable_baselines3 import SAC
        return SAC
    from sb3_contrib import RecurrentPPO
    return RecurrentPPO


@dataclass(frozen=True)
class Learner:
    """An algorithm's name turned into its learner once (`learner`): the name, the library that trains it and the
    class, which `millvib train` builds, resumes and saves with."""

    algo: str
    backend: str
    cls: Any

    def portable(self, path: Path) -> str:
        """The library the model saved at `path` is for, once made portable: an sbx SAC is rewritten as SB3's SAC
        with the same weights (`catalog.sbx_to_sb3`), so the agent loads, runs and exports without JAX (a run's
        checkpoints, for --resume, stay sbx's); any other model is left as it was trained."""
        if self.backend != "sbx" or self.algo != "sac":
            return self.backend
        sb3_sac_from_sbx(self.cls.load(path, device="cpu")).save(path)
        return "sb3"


def learner(algo: str, backend: str = "auto") -> Learner:
    """The `Learner` of an algorithm name (any case) and a backend ("auto": `resolved_backend`); a clear error for
    a name or backend there is none of."""
    algo = str(algo).lower()
    backend = resolved_backend(algo, backend)
    return Learner(algo, backend, algo_class(algo, backend))


#: what an agent's card may set in its environment: its action, observation and reward, never the
#: episode (plants, disturbances, start, length) that every controller of the task must share
AGENT_ENV_KEYS = frozenset({"config", "residual", "observe_params", "observe_phase", "actions", "observation",
                            "reward"})


def agent_env_kwargs(raw, task: Task, version: str) -> dict:
    """The env keyword arguments an agent trains with: a hyperparameter file's env_kwargs with their named gain sets
    resolved on `task` in env version `version` and the task's config. Refused when training starts (not when the
    finished agent is loaded) where a card could not carry them: not a mapping, a key that changes the episode
    (`AGENT_ENV_KEYS`), another task's config."""

    raw = raw or {}
    if not isinstance(raw, dict):
        raise ValueError(f"env_kwargs = {shown(raw)} in the hyperparameters is invalid: a mapping")
    episode_keys = sorted(set(raw) - AGENT_ENV_KEYS, key=repr)
    if episode_keys:
        raise ValueError(f"env_kwargs {episode_keys} in the hyperparameters would change the episode the agent "
                         f"meets (its plants, disturbances or start); allowed: {sorted(AGENT_ENV_KEYS)}")
    if "config" in raw and raw["config"] != task.config:
        raise ValueError(f"env_kwargs config = {shown(raw['config'])} in the hyperparameters is not task "
                         f"{shown(task.name)}'s ({shown(task.config)}): choose the task with --task")
    out = resolve_named_gains_for(raw, task, version)
    out["config"] = task.config  # every task's, startup's too: the card alone rebuilds the environment
    return out


#: the card's keys the project reads, with the type each must have
CARD_TYPES = {"env_id": str, "algo": str, "name": str, "task": str, "backend": str, "normalize": str,
              "env_kwargs": dict, "seed": int, "retired": str}
#: the largest card read (a card is a few kB)
MAX_CARD_BYTES = 2**20


def read_card(path: str | Path) -> dict:
    """An agent's card.json, validated as data: a regular JSON file of at most `MAX_CARD_BYTES`, a mapping whose
    keys of `CARD_TYPES` have their types (a seed a whole number in [0, 2^31)); otherwise a ValueError of one
    line naming the file (and the key)."""
    path = Path(path)
    try:
        if not path.is_file():
            raise ValueError("no such file" if not path.exists() else "not a regular file")
        if path.stat().st_size > MAX_CARD_BYTES:
            raise ValueError(f"larger than {MAX_CARD_BYTES // 2**20} MiB")
        card = json.loads(path.read_text(encoding="utf-8"))
    except RecursionError:
        raise ValueError(f"{shown_path(path)} is not a valid model card: nested too deeply") from None
    except OSError as err:
        raise ValueError(f"{shown_path(path)} cannot be read: {err.strerror or type(err).__name__}") from None
    except ValueError as err:  # JSON and Unicode errors too
        raise ValueError(f"{shown_path(path)} is not a valid model card: {str(err).splitlines()[0]}") from None
    if not isinstance(card, dict):
        raise ValueError(f"{shown_path(path)} is not a valid model card: a JSON object is needed, not "
                         f"{type(card).__name__}")
    for key, kind in CARD_TYPES.items():
        if key in card and (not isinstance(card[key], kind) or isinstance(card[key], bool)):
            raise ValueError(f"{shown_path(path)}: {key} = {shown(card[key])} is invalid: must be a JSON "
                             f"{ {str: 'string', dict: 'object', int: 'whole number'}[kind] }")
    if "seed" in card and not 0 <= card["seed"] < 2**31:
        raise ValueError(f"{shown_path(path)}: seed = {shown(card['seed'])} is invalid: a whole number in [0, 2^31)")
    return card


def card_task(card: dict) -> Task:
    """The task a card names (startup where it names none): resolved here, where the name enters from the file."""
    return get_task(card.get("task", "startup"))


def checked_card(folder: str | Path) -> dict:
    """The card of an agent folder, checked as data before any learner library loads: `read_card`'s types,
    the keys every card needs, the algorithm and backend, and env_kwargs that leave the episode alone."""
    folder = Path(folder)
    card_path = folder / "card.json"
    if not card_path.exists():
        raise ValueError(f"{shown_path(folder)} is not an agent folder: no card.json (see agents/README.md)")
    card = read_card(card_path)
    if "env_id" not in card or "algo" not in card:
        raise ValueError(f"{card_path} is not a valid model card: it needs at least 'algo' and 'env_id'")
    env_kwargs = card.get("env_kwargs", {})
    episode_keys = sorted(map(str, set(env_kwargs) - AGENT_ENV_KEYS))
    if episode_keys:
        raise ValueError(f"{card_path}: env_kwargs {episode_keys} would change the episode the agent meets (its "
                         f"plants, disturbances or start); a card may set only {sorted(AGENT_ENV_KEYS)}, so that "
                         "every controller of a task meets the same plants")
    if "config" in env_kwargs and env_kwargs["config"] != card_task(card).config:
        raise ValueError(f"{card_path}: env_kwargs config {shown(env_kwargs['config'])} is not its task's")
    algo = str(card["algo"]).lower()
    if algo not in ALGOS:
        raise ValueError(f"unknown algo {shown(algo)} in {card_path}: one of {ALGOS}")
    if str(card.get("backend", "sb3")) not in BACKENDS:
        raise ValueError(f"unknown backend {card.get('backend')!r} in {card_path}: one of {sorted(BACKENDS)}")
    return card


def check_agent(name: str) -> None:
    """Every seed folder's card and observation statistics of agent `name`, checked as data before torch and
    the learner libraries load (seconds), so a damaged file is refused at once (docs/guarantees.md)."""

    for folder in agent_seed_folders(agent_folder(name)).values():
        card = checked_card(folder)
        if normalizes_obs(card.get("normalize", "None"), f"{folder / 'card.json'}: normalize"):
            load_obs_stats(folder / STATS_FILE)


class AgentPolicy(Controller):
    """A trained SB3 agent (PPO, SAC or RecurrentPPO) with its VecNormalize observation statistics.

    Made from its folder, it checks the folder (the manifest of a shipped agent, the card, the files it needs and
    the statistics); its learner library (torch and SB3, 1 s at a process's first agent) and network load at the
    first use of `policy`, `model`, `obs_stats` or `predict`. A benchmark whose agents run in worker processes then
    loads none in the parent, which needs only their cards. A PPO or SAC saved by SB3 acts through its policy
    alone (`acting_policy`): the learner around it (`model`) loads only where asked for."""

    card: dict
    seed: int
    task: Task

    def __init__(self, folder: str | Path):

        folder = Path(folder)
        card_path = folder / "card.json"
        self.shipped = verify_agent(folder)
        self.card = checked_card(folder)
        self.name = self.card.get("name", folder.name)
        self.seed = self.card.get("seed", 0)
        self.env_id = self.card["env_id"]
        self.task = card_task(self.card)

        # a card may name the gain set its policy builds on (``residual_gains: pid-pf-robust``): numbers from here on
        # and the task's config, where an earlier card left it out (the plain SB3 recipe and an export read it)
        self.env_kwargs = resolve_named_gains_for({"config": self.task.config, **self.card.get("env_kwargs", {})},
                                                  self.task, version=env_version(self.env_id))
        self.algo = str(self.card["algo"]).lower()
        self.backend = str(self.card.get("backend", "sb3"))  # the library it was trained with
        self.model_format = str(self.card.get("model_format", self.backend))  # the library model.zip is for
        self.recurrent = self.algo == "recurrentppo"
        self._model_path = folder / "model.zip"
        if not self._model_path.is_file():
            raise ValueError(f"{shown_path(self._model_path)} is missing: not a complete agent folder")
        normalized = normalizes_obs(self.card.get("normalize", "None"), f"{card_path}: normalize")
        self._stats_path = folder / STATS_FILE if normalized else None
        if self._stats_path is not None:
            load_obs_stats(self._stats_path)  # a missing or broken file fails here, not at the first step
        self._model: Any = None
        self._policy: Any = None
        self._obs_stats: ObsStats | None = None
        self._act: Callable | None = None

    @property
    def _policy_only(self) -> bool:
        """Whether the agent acts through its policy alone (`acting_policy`): a PPO or SAC in SB3's format."""
        return self.model_format == "sb3" and self.algo in ("ppo", "sac")

    def _loaded(self, load: Callable) -> Any:
        try:
            return load()
        except Exception as err:
            raise ValueError(f"{shown_path(self._model_path)} cannot be loaded: {type(err).__name__}: "
                             f"{str(err)[:200]}") from None

    def _load(self) -> None:
        """The network (the policy alone where it acts so, else the learner) and the statistics (checked against
        the network's observations)."""
        if self._policy_only:
            one_torch_thread()  # a small network acts faster on one thread
            self._policy = self._loaded(lambda: acting_policy(self._model_path, self.algo))
        else:
            self._model = self._loaded(lambda: algo_class(self.algo, self.model_format).load(self._model_path,
                                                                                             device="cpu"))
            self._policy = self._model.policy
        if self._stats_path is not None:
            self._obs_stats = load_obs_stats(self._stats_path, int(self._policy.observation_space.shape[0]))
        self._act = None if self.recurrent or self.model_format != "sb3" else deterministic_actor(self._policy)

    @property
    def policy(self):
        """The network that acts (an SB3 or sbx policy), loaded at the first use."""
        if self._policy is None:
            self._load()
        return self._policy

    @property
    def model(self):
        """The learner (an SB3 or sbx algorithm object), loaded at the first use: for a PPO or SAC in SB3's format
        apart from the policy that acts, which keeps its own copy of the weights."""
        if self._model is None:
            if self._policy_only:
                one_torch_thread()
                self._model = self._loaded(lambda: algo_class(self.algo).load(self._model_path, device="cpu"))
            else:
                self._load()
        return self._model

    @property
    def obs_stats(self):
        """The VecNormalize observation statistics (`normalization.ObsStats`), or None where the agent has none."""
        if self._policy is None:
            self._load()
        return self._obs_stats

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        stats = self.obs_stats
        return obs if stats is None else stats.normalize(obs)

    def on_reset(self, infos, indices) -> None:
        self._own_start = True  # a plain loop's recurrent state starts afresh with the episode

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        obs = self.normalize(np.asarray(observation, dtype=np.float32))  # loads the agent at its first step
        if deterministic and self._act is not None:
            shape = self.policy.observation_space.shape
            if obs.shape == shape:
                return self._act(obs[None])[0], state
            if obs.shape[1:] == shape:
                return self._act(obs), state
        if self.recurrent:
            if state is None and episode_start is None and obs.ndim == 1:
                # a plain Gymnasium loop (ctrl.make_env()): the agent keeps its own LSTM state
                start = np.array([getattr(self, "_own_start", True)])
                action, self._own_state = self.model.predict(
                    obs, state=None if start[0] else getattr(self, "_own_state", None), episode_start=start,
                    deterministic=deterministic)
                self._own_start = False
                return action, None
            return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        return (self.policy if self._policy_only else self.model).predict(obs, deterministic=deterministic)


class _NoOptimizer:
    """What an acting policy gets for an optimiser (`acting_policy`): SB3's policies build theirs when they are
    made, and torch's optimisers import `torch._dynamo` at a process's first (a second's work: docs/performance.md)."""

    def __init__(self, params, **kwargs):
        pass


def acting_policy(path: str | Path, algo: str):
    """The policy of a PPO or SAC that SB3 saved at `path`, without its learner: made as SB3's ``load`` makes it
    (the same class, spaces and keyword arguments from the file, the same weights), with no optimiser, in eval
    mode. It acts as ``PPO.load(path).policy`` does (a test compares their actions); it cannot be trained."""
    from stable_baselines3.common.save_util import load_from_zip_file

    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.sac.policies import SACPolicy

    data, params, _ = load_from_zip_file(path, device="cpu")
    if data is None:
        raise ValueError("no data file in the archive")
    expected = {"ppo": ActorCriticPolicy, "sac": SACPolicy}.get(algo)
    found = data.get("policy_class")
    if expected is not None and not (isinstance(found, type) and issubclass(found, expected)):
        raise ValueError(f"the card's algo {algo!r} does not fit the model's policy "
                         f"{getattr(found, '__name__', found)!r} (a {expected.__name__} is needed)")
    kwargs = {k: v for k, v in data.get("policy_kwargs", {}).items() if k != "device"}  # as SB3's load
    kwargs["optimizer_class"] = _NoOptimizer
    if algo == "ppo":  # an on-policy learner passes its use_sde; an off-policy one keeps it in policy_kwargs
        kwargs["use_sde"] = data["use_sde"]
    policy = data["policy_class"](data["observation_space"], data["action_space"], lambda _: 0.0, **kwargs)
    policy.load_state_dict(params["policy"])
    policy.set_training_mode(False)
    return policy


def deterministic_actor(policy):
    """SB3's ``policy.predict(obs, deterministic=True)`` for a batch of observations, as a function, for the two
    policies the shipped agents have: PPO's (a diagonal Gaussian: its mean, clipped to the action space) and SAC's
    (a squashed Gaussian: tanh of its mean, rescaled). The same torch operations in the same order, without what
    `predict` does around them at every call (setting the training mode of every module, building the action
    distribution), in about half the time at batch 8; a test compares the actions with `predict`'s. None for
    any other policy, which `predict` then runs as SB3 does."""
    import torch as th
    from stable_baselines3.common.distributions import DiagGaussianDistribution, SquashedDiagGaussianDistribution
    from stable_baselines3.common.policies import ActorCriticPolicy, BaseModel
    from stable_baselines3.sac.policies import SACPolicy

    if type(policy) is ActorCriticPolicy and type(policy.action_dist) is DiagGaussianDistribution \
            and not policy.use_sde and not policy.squash_output:
        def mean(obs):
            features = BaseModel.extract_features(policy, obs, policy.pi_features_extractor)  # as get_distribution
            return policy.action_net(policy.mlp_extractor.forward_actor(features))
    elif type(policy) is SACPolicy and type(policy.actor.action_dist) is SquashedDiagGaussianDistribution \
            and not policy.actor.use_sde and policy.squash_output:
        actor = policy.actor

        def mean(obs):
            return th.tanh(actor.mu(actor.latent_pi(actor.extract_features(obs, actor.features_extractor))))
    else:
        return None
    policy.set_training_mode(False)
    space = policy.action_space

    def act(obs: np.ndarray) -> np.ndarray:
        with th.no_grad():
            actions = mean(th.as_tensor(np.array(obs), device=policy.device))
        actions = actions.cpu().numpy().reshape((-1, *space.shape))
        if policy.squash_output:
            return policy.unscale_action(actions)
        return np.clip(actions, space.low, space.high)

    return act


#: the folder of training seed s of a multi-seed agent: <agent>/seed-<s>/
SEED_FOLDER = re.compile(r"seed-(\d+)")


def agent_seed_folders(folder: str | Path) -> dict[int, Path]:
    """The seeds of an agent folder: {seed: folder} for a single agent (card.json in the folder), or
    one entry per `seed-<s>/` subfolder of a multi-seed agent (`millvib train --seeds`), by seed."""
    folder = Path(folder)
    if (folder / "card.json").exists():
        try:
            seed = int(read_card(folder / "card.json").get("seed", 0))
        except ValueError:
            seed = 0  # the card is refused in one line when the agent is loaded
        return {seed: folder}
    found = {}
    for p in folder.glob("seed-*"):
        m = SEED_FOLDER.fullmatch(p.name)
        if m and p.is_dir():  # a seed folder that lost its card is listed, and fails to load in one line
            found[int(m.group(1))] = p
    if found and not any((p / "card.json").exists() for p in found.values()):
        return {}
    return dict(sorted(found.items()))


def _agent_card_key(folder: Path, key: str, default: str) -> str:
    first = next(iter(agent_seed_folders(folder).values()))
    value = read_card(first / "card.json").get(key, default)
    return value if isinstance(value, str) else default


def _agent_task(folder: Path) -> str:
    return _agent_card_key(folder, "task", "startup")


def agent_base(name: str) -> str | None:
    """The controller an agent was trained on top of (its card's ``on``: a DAgger student's classical controller,
    e.g. pid-pf-preview), or None."""
    value = read_card(next(iter(agent_seed_folders(agent_folder(name)).values())) / "card.json").get("on")
    return value if isinstance(value, str) else None


def agent_validation_cost(name: str) -> float:
    """An agent's mean validation cost over its seeds (each card's ``validation.cost_mean``: its task's first
    validation plants, the plants it was selected on); inf where a card has none."""
    costs = []
    for folder in agent_seed_folders(agent_folder(name)).values():
        value = read_card(folder / "card.json").get("validation", {})
        cost = value.get("cost_mean") if isinstance(value, dict) else None
        costs.append(float(cost) if isinstance(cost, (int, float)) and not isinstance(cost, bool) else float("inf"))
    return float(sum(costs) / len(costs)) if costs else float("inf")


def _agent_version(folder: Path) -> str:
    env_id = _agent_card_key(folder, "env_id", "MillVib-GainSchedule-v0")
    return env_id.rsplit("-", 1)[-1]


def agent_retired(name: str) -> str | None:
    """Why a shipped agent is retired (its card's ``retired``: superseded, kept so that earlier results can be
    repeated; loaded by name, left out of a benchmark's default lineup), or None."""
    value = _agent_card_key(agent_folder(name), "retired", "")
    return value or None


@takes_task()
def list_agents(task: str | Task | None = None, version: str | None = None, retired: bool = True) -> list[str]:
    """Shipped agents (folders under agents/ with a card, or with seed-<s>/ folders that have one),
    optionally only those trained on `task`, those trained in environment version `version`, and not the retired
    ones (`retired=False`: `agent_retired`)."""
    assert task is None or isinstance(task, Task)  # a name was resolved by @takes_task
    wanted = None if task is None else task.name
    root = agents_dir()
    if not root.is_dir():
        return []
    names = []
    for p in sorted(root.iterdir()):
        if p.is_dir() and agent_seed_folders(p):
            if wanted is not None and _agent_task(p) != wanted:
                continue
            if version is not None and _agent_version(p) != version:
                continue
            if not retired and _agent_card_key(p, "retired", ""):
                continue
            names.append(p.name)
    return names


def agent_folder(name: str) -> Path:
    """The folder of an agent given by name (a shipped agent under agents/: always that one, even where
    a folder of the same name lies in the working directory) or by path; ValueError if there is none.
    A shipped agent that is a symbolic link is refused: the manifest covers real folders only."""
    if isinstance(name, Path):
        name = str(name)
    if not isinstance(name, str) or not name:
        raise ValueError(f"agent = {shown(name)} is invalid: a shipped agent's name {list_agents()} or an agent "
                         "folder's path")
    shipped = agents_dir() / name
    if "/" not in name and "\\" not in name and name not in (".", "..") and shipped.is_dir():
        if shipped.is_symlink() or any(p.is_symlink() for p in shipped.iterdir()):
            raise ValueError(f"agents/{name} is (or holds) a symbolic link: shipped agents are real folders covered "
                             "by agents/MANIFEST.sha256")
        path = shipped
    else:
        path = Path(name)
    if not path.is_dir() or not agent_seed_folders(path):
        raise ValueError(f"controller {shown(name)} unknown: use one of {baseline_names()}, a shipped agent "
                         f"{list_agents()}, an agent folder path (a folder with card.json, or seed-<s>/ "
                         "folders that have one) or an exported agent's FILE.onnx (millvib export)")
    return path


def agent_seeds(name: str) -> list[int]:
    """The training seeds an agent ships (one for a single-seed folder)."""
    return list(agent_seed_folders(agent_folder(name)))
