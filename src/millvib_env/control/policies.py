"""Controllers with Stable-Baselines3's `predict` signature, so one evaluation loop runs them all.

* `FixedGainPolicy`: a PID with fixed gains, acting in the gain-schedule environment by holding the
  action that maps to its gains (pid-paper, pid-nominal, pid-robust).
* `OraclePolicy`: knows the plant's true c1 and Ct (the evaluation loop hands it ``info["params"]``
  at every reset and step) and uses gains tuned offline for that plant, interpolated on a
  (log c1, log Ct) grid: the bound for a fixed-gain PID on a fixed plant, not a deployable
  controller. On the `change` task it takes the table's gains for the plant of the moment (the
  `rolling` table): no longer a bound there, since gains tuned for fixed plants need not handle
  the change itself.
* `LQRPolicy` (`lqr-oracle`): knows c1 and Ct and designs an LQR with integral action for the
  PID + pressure-feedback structure on the linearised plant (`control.lqr`).
* `AdaptivePolicy` (`pid-adaptive`, `control.adaptive`): estimates c1 and Ct online from what a
  mill measures and takes the oracle's gains for the estimate: deployable.
* `AgentPolicy`: a trained SB3 model with its VecNormalize statistics.

The gains of the baselines and how they were found live in configs/control/<task>.yaml.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from millvib_env._paths import agents_dir, config_dir
from millvib_env._yaml import load_yaml
from millvib_env.control.base import Controller, ControllerLoop, GainTable, PerEnvGains
from millvib_env.envs.actions import GainMap
from millvib_env.envs.config import EnvConfig, load_env_config
from millvib_env.params import PAPER_GAINS
from millvib_env.tasks import get_task

__all__ = ["Controller", "FixedGainPolicy", "OraclePolicy", "LQRPolicy", "AgentPolicy", "GainTable",
           "load_controller", "baseline_names", "ControllerLoop", "named_gains", "REFERENCE", "list_agents", "agent_seeds", "agent_seed_folders", "agent_folder", "load_control_config", "BASELINES",
           "BACKENDS", "algo_class"]

#: every baseline by name, with what it is
BASELINES = {
    "pid-paper": "the paper's PID (KP = 1e5, KI = 1e-3, KD = 0)",
    "pid-nominal": "tuned on the task's nominal plant only (Table 1 c1 and Ct), as a PID is commissioned",
    "pid-robust": "one set of gains minimising the mean cost over the task's tuning plants",
    "pid-oracle": "knows the true c1 and Ct; gains tuned offline per plant (grid, interpolated); not deployable",
    "pid-adaptive": "estimates c1 and Ct online (RLS with forgetting) and takes the oracle's gains for the estimate",
    "lqr-oracle": "knows the true c1 and Ct; LQR with integral action for PID + pressure feedback on the "
                  "linearised plant; not deployable",
    "pid-pf-robust": "one fixed PID + pressure feedback (KP, KI, KD, KPL) for the task's whole range of c1 and Ct: "
                     "the active damping a plant engineer commissions; the benchmark's reference",
    "pid-pf-ff": "pid-pf-robust plus a feedforward of the load cells' rolling-force deviation (KFF), all five gains "
                 "tuned together: the classical opponent of a controller that reads the load cells",
    "pid-pf-oracle": "knows the true c1 and Ct; PID + pressure-feedback gains tuned offline per plant (grid, "
                     "interpolated): the bound for gain scheduling with pressure feedback on a fixed plant",
}
#: the benchmark's default reference: the strongest deployable classical controller
REFERENCE = "pid-pf-robust"


class FixedGainPolicy(Controller):
    """A fixed-gain controller (a PID, + pressure feedback with 4 gains, + force feedforward with 5). It
    runs in an env whose action is relative to its gains with zero range (`fixed_actions`), so the
    gains that run are exactly the ones given: never clipped to an action's bounds (a 1e12 gain in a
    config runs as 1e12, or is refused if it is negative or not finite)."""

    def __init__(self, name: str, gains, gain_map: GainMap | None = None, description: str = ""):
        from millvib_env.envs.actions import fixed_actions

        self.name, self.description = name, description
        self.gains = np.asarray(gains.to_array() if hasattr(gains, "to_array") else gains, float)
        self.env_kwargs = {"actions": fixed_actions(self.gains)}
        self._action = np.zeros(len(self.gains), dtype=np.float32)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        obs = np.asarray(observation)
        if obs.ndim == 1:
            return self._action.copy(), state
        return np.tile(self._action, (obs.shape[0], 1)), state

    def __repr__(self) -> str:
        return f"FixedGainPolicy({self.name}, gains={np.array2string(self.gains, precision=3)})"


class OraclePolicy(PerEnvGains):
    """Per-plant gains from the offline-tuned grid (`GainTable`) for the true (c1, Ct); a table of
    four gains (pid-pf-oracle) runs with pressure feedback in the wide-bounds action."""

    name = "pid-oracle"

    def __init__(self, table: GainTable, gain_map: GainMap, name: str = "pid-oracle", task: str | None = None):
        self.table, self.gain_map, self.name = table, gain_map, name
        if table.log_gains.shape[-1] > 3:
            from millvib_env.envs.actions import wide_actions

            self.env_kwargs = {"actions": wide_actions(table.log_gains.shape[-1])}
            self.gain_map = GainMap.from_config(load_env_config(get_task(task or "startup").config,
                                                                **self.env_kwargs))
        self._actions = None

    def gains_for(self, c1: float, ct: float) -> np.ndarray:
        return self.table(c1, ct)


class LQRPolicy(PerEnvGains):
    """`lqr-oracle`: LQR gains (PID + pressure feedback) designed for the true (c1, Ct)."""

    name = "lqr-oracle"
    #: the gain-schedule env with the pressure-feedback action, linearly scaled (the LQR's position
    #: gain can be negative when its pressure feedback carries the position loop); KD keeps the
    #: same 300 V s/m limit as every other controller
    ENV_KWARGS = {"actions": {"pressure_feedback": True, "scale": "linear", "kp": [-2.0e7, 2.0e7],
                              "ki": [0.0, 1.0e9], "kd": [0.0, 300.0], "kpl": [0.0, 1.0e-2]}}

    def __init__(self, weights, base_params, task: str):
        from millvib_env.control.lqr import lqr_gains

        self.weights, self.base_params = weights, base_params
        self.env_kwargs = dict(self.ENV_KWARGS)
        self.gain_map = GainMap.from_config(load_env_config(get_task(task).config, **self.env_kwargs))
        self._lqr = lqr_gains
        self._actions = None
        self.clipped = 0

    def gains_for(self, c1: float, ct: float) -> np.ndarray:
        g = self._lqr(self.base_params.replace(c1=c1, Ct=ct), self.weights)
        if np.any(g < self.gain_map.lo) or np.any(g > self.gain_map.hi):
            self.clipped += 1
        return g


#: the algorithms an agent may be trained with (`millvib train --algo`)
ALGOS = ("ppo", "sac", "recurrentppo")
#: the learner libraries (`millvib train --backend`): Stable-Baselines3 (PyTorch, the default) and sbx,
#: its JAX port (`pip install -e '.[sbx]'`), for PPO and SAC; a model card records its backend
BACKENDS = {"sb3": ALGOS, "sbx": ("ppo", "sac")}


def algo_class(algo: str, backend: str = "sb3"):
    """The learner class of an algorithm name for a backend (SB3, sb3-contrib or sbx); imported only
    when asked for."""
    if backend not in BACKENDS:
        raise ValueError(f"backend = {backend!r} is invalid: one of {sorted(BACKENDS)}")
    if algo not in BACKENDS[backend]:
        raise ValueError(f"algo = {algo!r} is invalid for backend {backend!r}: one of {BACKENDS[backend]}")
    if backend == "sbx":
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


#: what an agent's card may set in its environment: its action, observation and reward, never the
#: episode (plants, disturbances, start, length) that every controller of the task must share
AGENT_ENV_KEYS = frozenset({"config", "residual", "observe_params", "observe_phase", "actions", "observation",
                            "reward"})


class AgentPolicy(Controller):
    """A trained SB3 agent (PPO, SAC or RecurrentPPO) with its VecNormalize observation statistics."""

    def __init__(self, folder: str | Path):
        from millvib_env.control.manifest import verify_agent

        folder = Path(folder)
        card_path = folder / "card.json"
        if not card_path.exists():
            raise ValueError(f"{folder} is not an agent folder: no card.json (see agents/README.md)")
        self.shipped = verify_agent(folder)
        try:
            self.card = json.loads(card_path.read_text())
            self.card["env_id"], self.card["algo"]
        except (ValueError, KeyError, TypeError) as err:
            raise ValueError(f"{card_path} is not a valid model card ({type(err).__name__}: {err}); it needs at "
                             "least 'algo' and 'env_id'") from None
        self.name = self.card.get("name", folder.name)
        self.seed = self.card.get("seed", 0)
        self.env_id = self.card["env_id"]
        self.task = self.card.get("task", "startup")
        self.env_kwargs = dict(self.card.get("env_kwargs", {}))
        episode_keys = sorted(set(self.env_kwargs) - AGENT_ENV_KEYS)
        if episode_keys:
            raise ValueError(f"{card_path}: env_kwargs {episode_keys} would change the episode the agent meets (its "
                             f"plants, disturbances or start); a card may set only {sorted(AGENT_ENV_KEYS)}, so that "
                             "every controller of a task meets the same plants")
        if "config" in self.env_kwargs and self.env_kwargs["config"] != get_task(self.card.get("task", "startup")).config:
            raise ValueError(f"{card_path}: env_kwargs config {self.env_kwargs['config']!r} is not its task's")
        algo = str(self.card["algo"]).lower()
        if algo not in ALGOS:
            raise ValueError(f"unknown algo {algo!r} in {card_path}: one of {ALGOS}")
        self.backend = str(self.card.get("backend", "sb3"))
        if self.backend not in BACKENDS:
            raise ValueError(f"unknown backend {self.backend!r} in {card_path}: one of {sorted(BACKENDS)}")
        cls = algo_class(algo, self.backend)
        self.recurrent = algo == "recurrentppo"
        model_path = folder / "model.zip"
        if not model_path.is_file():
            raise ValueError(f"{model_path} is missing: not a complete agent folder")
        try:
            self.model = cls.load(model_path, device="cpu")
        except Exception as err:
            raise ValueError(f"{model_path} cannot be loaded: {type(err).__name__}: {str(err)[:200]}") from None
        self.obs_stats = None
        normalize = self.card.get("normalize", "None")
        if not isinstance(normalize, str) or normalize.strip() not in ("None", "False", "", "{}") and \
                not normalize.strip().startswith(("{", "dict(")):
            raise ValueError(f"{card_path}: normalize = {normalize!r} is invalid: 'None' or the VecNormalize "
                             "arguments as train writes them (e.g. \"{'norm_obs': True, 'norm_reward': True}\")")
        if normalize.strip() not in ("None", "False", "", "{}"):
            from millvib_env.control.normalization import STATS_FILE, load_obs_stats

            self.obs_stats = load_obs_stats(folder / STATS_FILE, int(self.model.observation_space.shape[0]))

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        return obs if self.obs_stats is None else self.obs_stats.normalize(obs)

    def on_reset(self, infos, indices) -> None:
        self._own_start = True  # a plain loop's recurrent state starts afresh with the episode

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        obs = self.normalize(np.asarray(observation, dtype=np.float32))
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
        return self.model.predict(obs, deterministic=deterministic)


def load_control_config(task: str = "startup") -> dict[str, Any]:
    """configs/control/<task>.yaml: the task's tuned baselines (an entry may say `from_task: NAME`)."""
    name = get_task(task).name
    path = config_dir() / "control" / f"{name}.yaml"
    if not path.is_file():
        raise ValueError(f"no tuned baselines for task {name!r}: {path} is missing (run millvib tune "
                         f"--task {name} --write-config)")
    return load_yaml(path)


def _entry(task: str, name: str) -> dict:
    data = load_control_config(task)
    if name not in data:
        raise ValueError(f"configs/control/{get_task(task).name}.yaml has no entry {name!r} (run millvib tune "
                         f"--task {get_task(task).name} --only {name} --write-config)")
    entry = data[name]
    if "from_task" in entry:
        return _entry(entry["from_task"], name)
    return entry


def baseline_names() -> list[str]:
    return list(BASELINES)


def _checked_gains(task: str, name: str, entry: dict) -> list[float]:
    """An entry's gains (`envs.config.checked_gains`)."""
    from millvib_env.envs.config import checked_gains

    return checked_gains(entry.get("gains") if isinstance(entry, dict) else None,
                         f"configs/control/{get_task(task).name}.yaml {name}.gains")


def named_gains(task: str, name: str) -> list[float]:
    """The gains of a fixed-gain baseline of `task` (pid-robust, pid-pf-robust, pid-pf-ff, ...), as a
    config may name them for a residual or relative action's base (`envs.config.named_gains`)."""
    from millvib_env.envs.config import named_gains as _named

    return _named(name, get_task(task).name)


#: the folder of training seed s of a multi-seed agent: <agent>/seed-<s>/
SEED_FOLDER = re.compile(r"seed-(\d+)")


def agent_seed_folders(folder: str | Path) -> dict[int, Path]:
    """The seeds of an agent folder: {seed: folder} for a single agent (card.json in the folder), or
    one entry per `seed-<s>/` subfolder of a multi-seed agent (`millvib train --seeds`), by seed."""
    folder = Path(folder)
    if (folder / "card.json").exists():
        try:
            seed = int(json.loads((folder / "card.json").read_text()).get("seed", 0))
        except (ValueError, TypeError, AttributeError):
            seed = 0
        return {seed: folder}
    found = {}
    for p in folder.glob("seed-*"):
        m = SEED_FOLDER.fullmatch(p.name)
        if m and p.is_dir():  # a seed folder that lost its card is listed, and fails to load in one line
            found[int(m.group(1))] = p
    if found and not any((p / "card.json").exists() for p in found.values()):
        return {}
    return dict(sorted(found.items()))


def _agent_task(folder: Path) -> str:
    first = next(iter(agent_seed_folders(folder).values()))
    try:
        return json.loads((first / "card.json").read_text()).get("task", "startup")
    except (ValueError, AttributeError) as err:
        raise ValueError(f"{first / 'card.json'} is not a valid model card: {err}") from None


def list_agents(task: str | None = None) -> list[str]:
    """Shipped agents (folders under agents/ with a card, or with seed-<s>/ folders that have one),
    optionally only those trained on `task`."""
    root = agents_dir()
    if not root.is_dir():
        return []
    names = []
    for p in sorted(root.iterdir()):
        if p.is_dir() and agent_seed_folders(p):
            if task is not None and _agent_task(p) != get_task(task).name:
                continue
            names.append(p.name)
    return names


def agent_folder(name: str) -> Path:
    """The folder of an agent given by name (a shipped agent under agents/: always that one, even where
    a folder of the same name lies in the working directory) or by path; ValueError if there is none.
    A shipped agent that is a symbolic link is refused: the manifest covers real folders only."""
    shipped = agents_dir() / name
    if "/" not in name and "\\" not in name and name not in (".", "..") and shipped.is_dir():
        if shipped.is_symlink() or any(p.is_symlink() for p in shipped.iterdir()):
            raise ValueError(f"agents/{name} is (or holds) a symbolic link: shipped agents are real folders covered "
                             "by agents/MANIFEST.sha256")
        path = shipped
    else:
        path = Path(name)
    if not path.is_dir() or not agent_seed_folders(path):
        raise ValueError(f"controller {name!r} unknown: use one of {baseline_names()}, a shipped agent "
                         f"{list_agents()} or an agent folder path (a folder with card.json, or seed-<s>/ "
                         "folders that have one)")
    return path


def agent_seeds(name: str) -> list[int]:
    """The training seeds an agent ships (one for a single-seed folder)."""
    return list(agent_seed_folders(agent_folder(name)))


def oracle_table(task: str, name: str = "pid-oracle") -> GainTable:
    entry = _entry(task, name)
    return GainTable(entry["c1_grid"], entry["ct_grid"], np.array(entry["log10_gains"]))


def load_controller(name: str, task: str | None = None, config: EnvConfig | None = None,
                    seed: int | None = None) -> Controller:
    """A controller by name for `task`: a baseline (`BASELINES`), a shipped agent (agents/<name>) or
    an agent folder path. `seed` picks a training seed of a multi-seed agent (default: its lowest).
    `task` defaults to the agent's own (startup for a baseline); an agent trained on another task
    than the one asked for is refused."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"controller {name!r} is invalid: a baseline {baseline_names()} or an agent name or path")
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
    gain_map = GainMap.from_config(config or load_env_config(get_task(task).config))
    ctrl: Controller
    if name == "pid-paper":
        ctrl = FixedGainPolicy(name, PAPER_GAINS, gain_map, BASELINES[name])
    elif name in ("pid-nominal", "pid-robust", "pid-pf-robust", "pid-pf-ff"):
        entry = _entry(task, name)
        ctrl = FixedGainPolicy(name, _checked_gains(task, name, entry), gain_map, entry.get("how", ""))
    elif name in ("pid-oracle", "pid-pf-oracle"):
        ctrl = OraclePolicy(oracle_table(task, name), gain_map, name, task)
    elif name == "lqr-oracle":
        from millvib_env.control.lqr import LQRWeights

        entry = _entry(task, name)
        ctrl = LQRPolicy(LQRWeights(**entry["weights"]), load_env_config(get_task(task).config).base_params, task)
    elif name == "pid-adaptive":
        from millvib_env.control.adaptive import AdaptivePolicy, EstimatorSettings

        entry = _entry(task, name)
        cfg = config or load_env_config(get_task(task).config)
        ctrl = AdaptivePolicy(oracle_table(task), gain_map, EstimatorSettings(**entry["estimator"]), cfg.base_params,
                              sample_rate_hz=cfg.sample_rate_hz)
    ctrl.task = task
    return ctrl
