"""An exported agent (`millvib export`, `catalog.export`) run as a controller through onnxruntime, without torch,
SB3 or JAX: ``load_controller("student.onnx")``, ``millvib benchmark --controllers student.onnx``.

The graph holds the whole policy (observation statistics, actor, clip), and its metadata says where it runs: the
environment id and keyword arguments of the agent's card (gains as numbers), its task, its training seed and the
observation's channels. Everything read from the file is checked as data before it is used: a graph whose
metadata is missing or of the wrong kind, whose settings could change the episode the agent meets (the same rule
as a card's), or whose observation channels are not the ones its environment gives now (exported under another
version of the package) is refused in one line. The actions are the agent's own within float32 rounding
(`catalog.export.EXPORT_TOLERANCE`, checked when the file was written), so its benchmark rows are the agent's
within the same rounding (tests/test_export.py). ``pip install -e '.[export]'`` installs onnxruntime.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from millvib_env._checks import shown, shown_path
from millvib_env.catalog.agents import AGENT_ENV_KEYS, card_task
from millvib_env.control.base import Controller
from millvib_env.envs.batch import ENV_IDS, EpisodeBatch
from millvib_env.tasks import Task

__all__ = ["OnnxPolicy", "is_onnx_name"]

#: the metadata keys `catalog.export` writes that a controller needs
_NEEDED = ("millvib.agent", "millvib.seed", "millvib.task", "millvib.env_id", "millvib.env_kwargs",
           "millvib.observation")


def is_onnx_name(name: str) -> bool:
    """A controller name that is an exported graph's path (``*.onnx``)."""
    return isinstance(name, str) and name.lower().endswith(".onnx")


def _runtime():
    try:
        import onnxruntime
    except ImportError:
        raise ValueError("an exported policy (.onnx) runs through onnxruntime: pip install -e '.[export]'") from None
    return onnxruntime


def _metadata(path: Path, meta: dict) -> tuple[str, int, Task, str, dict, list]:
    """The graph's metadata, checked: (agent, seed, task, env_id, env_kwargs, observation names)."""
    missing = [k for k in _NEEDED if k not in meta]
    if missing:
        raise ValueError(f"{shown_path(path)}: metadata {missing} missing: not a graph written by `millvib export`")

    def parsed(key: str, kind: type):
        try:
            value = json.loads(meta[key])
        except ValueError:
            value = None
        if not isinstance(value, kind) or isinstance(value, bool):
            raise ValueError(f"{shown_path(path)}: metadata {key} = {shown(meta[key])} is invalid: a JSON "
                             f"{ {dict: 'object', list: 'list', int: 'whole number'}[kind] }")
        return value

    seed = parsed("millvib.seed", int)
    env_kwargs = parsed("millvib.env_kwargs", dict)
    obs_names = parsed("millvib.observation", list)
    env_id = meta["millvib.env_id"]
    if env_id not in ENV_IDS:
        raise ValueError(f"{shown_path(path)}: metadata millvib.env_id = {shown(env_id)} is invalid: one of "
                         f"{sorted(ENV_IDS)}")
    episode_keys = sorted(map(str, set(env_kwargs) - AGENT_ENV_KEYS))
    if episode_keys:
        raise ValueError(f"{shown_path(path)}: env_kwargs {episode_keys} would change the episode the policy meets; "
                         f"an exported policy may set only {sorted(AGENT_ENV_KEYS)}")
    task = card_task({"task": meta["millvib.task"]})  # the task's name enters from the file here
    return meta["millvib.agent"], seed, task, env_id, env_kwargs, obs_names


class OnnxPolicy(Controller):
    """An agent exported by `millvib export`, acting through onnxruntime (one thread, CPU) in the environment its
    metadata names. Runs as its agent does in every loop (the benchmark, `run_episodes`, `make_env`); it has one
    training seed, the one that was exported."""

    task: Task

    def __init__(self, path: str | Path):
        path = Path(path)
        ort = _runtime()
        try:
            data = path.read_bytes()
        except OSError as err:
            raise ValueError(f"controller {str(path)!r} cannot be read: {err.strerror or type(err).__name__}") \
                from None
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        try:
            session = ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
        except Exception as err:  # onnxruntime's own errors (InvalidProtobuf, Fail, ...) have no common base
            raise ValueError(f"{shown_path(path)} is not an ONNX graph onnxruntime can run: "
                             f"{str(err).strip().splitlines()[0][:200] if str(err).strip() else type(err).__name__}"
                             ) from None
        agent, self.seed, self.task, self.env_id, self.env_kwargs, obs_names = \
            _metadata(path, dict(session.get_modelmeta().custom_metadata_map))
        inputs, outputs = [i.name for i in session.get_inputs()], [o.name for o in session.get_outputs()]
        if inputs != ["observation"] or "action" not in outputs:
            raise ValueError(f"{shown_path(path)}: the graph takes {inputs} and gives {outputs}; an exported policy "
                             "takes ['observation'] and gives 'action'")
        have = list(EpisodeBatch(self.env_id, 1, **self.env_kwargs_for(self.task)).core.obs_names)
        if obs_names != have:
            raise ValueError(f"{shown_path(path)}: the graph reads the observation {obs_names}, but {self.env_id} "
                             f"gives {have} now: export the agent again with this version")
        self.name = path.name
        self.agent = agent
        self.path = path
        self._session = session

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """The agent's deterministic action (SB3's ``predict(obs, deterministic=True)``), for one observation or
        a batch; a stochastic action is not in the graph."""
        obs = np.asarray(observation, dtype=np.float32)
        one = obs.ndim == 1
        action = self._session.run(["action"], {"observation": obs[None] if one else obs})[0]
        return (action[0] if one else action), state
