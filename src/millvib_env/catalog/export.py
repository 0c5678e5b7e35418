"""A trained agent as one ONNX graph, for a mill's controller outside Python (`millvib export`).

The graph takes the observation as the environment gives it (float32, the channels of the card's environment,
in `obs_names` order) and returns the action SB3's ``predict(obs, deterministic=True)`` returns: the agent's
VecNormalize statistics (mean, variance, clip) come first, then the actor (PPO: the policy's mean action;
SAC: the actor's squashed mean), then the clip to the action space [-1, 1]. The model's metadata says what
the numbers mean: the observation's channels, the action's scale (volts per unit for a valve agent; its
residual's base gains), the loop's rate and the card's environment. The export follows SB3's own recipe
(docs: "Exporting models", ONNX) with PyTorch's exporter, and is checked: onnxruntime runs the graph on the
observations of a real episode of the agent's task and every action must equal the agent's own within
1e-5 (float32 rounding); the time per call at batch 1 is measured beside it (a figure of this machine,
printed, never asserted).

A SAC trained with sbx (JAX) is exported through the same SB3 networks, weight for weight (`catalog.sbx_to_sb3`),
and checked against its own sbx actions. Recurrent agents (RecurrentPPO) and sbx's PPO are not exported: their
state or their framework needs another path. ``pip install -e '.[export]'`` installs onnx and onnxruntime.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from millvib_env._checks import integer, shown
from millvib_env._paths import atomic_path
from millvib_env.catalog.agents import AgentPolicy, check_agent, list_agents
from millvib_env.catalog.factory import load_controller
from millvib_env.catalog.registry import baseline_names
from millvib_env.catalog.sbx_to_sb3 import sb3_sac_from_sbx
from millvib_env.envs.batch import EpisodeBatch

__all__ = ["export_agent", "ONNX_OPSET", "EXPORT_TOLERANCE"]

#: the ONNX operator set the graph is written in (onnxruntime 1.17+ runs it)
ONNX_OPSET = 17
#: the largest difference allowed between the graph's action and the agent's own (float32 rounding of a
#: few hundred multiply-adds, on actions in [-1, 1])
EXPORT_TOLERANCE = 1e-5


def _modules():
    try:
        import onnx
        import onnxruntime
    except ImportError:
        raise ValueError("export needs onnx and onnxruntime: pip install -e '.[export]'") from None
    return onnx, onnxruntime


def _deployed(agent):
    """A torch module: raw observation -> normalised -> actor -> clipped action (what `predict` does); an sbx SAC's
    networks as SB3's (`sb3_sac_from_sbx`)."""
    import torch

    stats = agent.obs_stats
    algo = str(agent.card["algo"]).lower()
    policy = sb3_sac_from_sbx(agent.model).policy if agent.model_format == "sbx" else agent.policy

    class Deployed(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.policy = policy
            dim = int(policy.observation_space.shape[0])
            mean = np.zeros(dim) if stats is None else stats.mean
            scale = np.ones(dim) if stats is None else np.sqrt(stats.var + stats.epsilon)
            self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32))
            self.register_buffer("scale", torch.as_tensor(scale, dtype=torch.float32))
            self.clip = float(stats.clip_obs) if stats is not None else float("inf")

        def forward(self, observation):
            x = (observation - self.mean) / self.scale
            if self.clip != float("inf"):
                x = torch.clamp(x, -self.clip, self.clip)
            if algo == "sac":  # SAC's deterministic action: the squashed mean (no distribution object traced)
                action = torch.tanh(self.policy.actor.get_action_dist_params(x)[0])
            else:  # PPO's deterministic action: the Gaussian's mean (no distribution object in the graph)
                features = self.policy.extract_features(x, self.policy.pi_features_extractor)
                action = self.policy.action_net(self.policy.mlp_extractor.forward_actor(features))
                if self.policy.squash_output:
                    action = torch.tanh(action)
            return torch.clamp(action, -1.0, 1.0)

    return Deployed().eval()


def _episode_observations(agent, steps: int) -> tuple[np.ndarray, Any]:
    """The observations of the agent's own first `steps` steps on its task's first validation plant."""

    t = agent.task
    venv = EpisodeBatch(agent.env_id, 1, **agent.env_kwargs_for(t))
    obs = venv.reset([t.seeds["validation"].start])
    seen = []
    for _ in range(steps):
        seen.append(np.asarray(obs, dtype=np.float32).copy())
        action, _ = agent.predict(obs, deterministic=True)
        obs, done, _ = venv.step(action)
        if done.all():
            break
    return np.concatenate(seen), venv.core


def _metadata(agent, core) -> dict:
    st = core.settings
    acts = st.cfg.actions
    meta = {"millvib.agent": agent.name, "millvib.seed": str(agent.seed), "millvib.task": agent.task.name,
            "millvib.env_id": agent.env_id, "millvib.env_kwargs": json.dumps(agent.env_kwargs, sort_keys=True),
            "millvib.observation": json.dumps(list(core.obs_names)),
            "millvib.period_s": repr(st.period_s), "millvib.mode": st.mode}
    if st.mode == "valve":
        meta["millvib.action"] = ("residual command (V) = action * " if st.residual else "command (V) = action * ") \
            + repr(st.u_range) + (", added to the digital PID's command (gains KP, KI, KD, KPL, KFF: "
                                    f"{[float(g) for g in st.residual_gains.to_array()]})"
                                    + (" and the fixed feedforward of env_kwargs' actions.residual_feedforward"
                                       if core.feedforward is not None else "")
                                    + ", and limited with it to the amplifier's range" if st.residual else "")
    else:
        meta["millvib.action"] = f"gain schedule in [-1, 1]^{st.act_dim} (envs.actions.GainMap of the env config: " \
            f"{json.dumps({k: acts.bounds(k) for k in ('kp', 'ki', 'kd', 'kpl', 'kff')})})"
    return meta


def export_agent(name: str, out: str | Path, *, seed: int | None = None, check_steps: int = 400,
                 latency_calls: int = 2000) -> dict:
    """Write agent `name` (a shipped agent or a folder; training seed `seed`, default its lowest) as an ONNX
    graph at `out`, checked against the agent on `check_steps` observations of one of its task's episodes;
    return a summary (the file, its inputs, the largest difference, the time per call at batch 1)."""
    import io

    check_steps = integer("check_steps", check_steps, lo=1, hi=100_000)
    latency_calls = integer("latency_calls", latency_calls, lo=0, hi=1_000_000)
    if name not in baseline_names() or name in list_agents():
        check_agent(name)  # its files, before torch and onnx load
    import torch

    onnx, ort = _modules()
    agent = load_controller(name, seed=seed, version="v1")
    if not isinstance(agent, AgentPolicy):
        raise ValueError(f"{shown(name)} is a baseline, not a trained agent: export takes an agent name or folder")
    algo = str(agent.card["algo"]).lower()
    if agent.recurrent or algo not in ("ppo", "sac") or (agent.model_format != "sb3" and algo != "sac"):
        raise ValueError(f"agent {shown(agent.name)} ({algo}, {agent.backend}) cannot be exported: export covers SB3's "
                         "PPO and SAC and sbx's SAC (a recurrent policy's state and sbx's PPO need another path)")
    obs, core = _episode_observations(agent, check_steps)
    module = _deployed(agent)
    dim = obs.shape[1]
    buf = io.BytesIO()
    import warnings

    # PyTorch's TorchScript-based exporter: the torch.export-based default needs onnxscript as well, and an MLP
    # needs nothing it adds; torch warns that the older path is deprecated (the pinned torch has it)
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(module, (torch.zeros(1, dim),), buf,  # type: ignore[arg-type]  # a file object too
                          dynamo=False, opset_version=ONNX_OPSET,
                          input_names=["observation"], output_names=["action"],
                          dynamic_axes={"observation": {0: "batch"}, "action": {0: "batch"}})
    model = onnx.load_from_string(buf.getvalue())
    onnx.helper.set_model_props(model, _metadata(agent, core))
    onnx.checker.check_model(model)
    data = model.SerializeToString()

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    session = ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
    got = session.run(["action"], {"observation": obs})[0]
    want = agent.predict(obs, deterministic=True)[0]
    diff = float(np.max(np.abs(got - want)))
    if not diff <= EXPORT_TOLERANCE:
        raise ValueError(f"the exported graph's actions differ from the agent's by {diff:.3g} (allowed "
                         f"{EXPORT_TOLERANCE:g}): not written")
    with atomic_path(out) as tmp:
        Path(tmp).write_bytes(data)
    summary = {"out": str(out), "agent": agent.name, "seed": agent.seed, "task": agent.task.name, "inputs": dim,
               "observation": list(core.obs_names), "opset": ONNX_OPSET, "checked_observations": len(obs),
               "max_abs_difference": diff}
    if latency_calls:
        one = obs[:1]
        times = np.empty(latency_calls)
        for i in range(latency_calls):
            start = time.perf_counter()
            session.run(["action"], {"observation": one})
            times[i] = time.perf_counter() - start
        summary["latency_us"] = {"median": round(float(np.median(times)) * 1e6, 1),
                                 "p99": round(float(np.percentile(times, 99)) * 1e6, 1),
                                 "loop_period_us": round(core.settings.period_s * 1e6, 1),
                                 "note": "onnxruntime, one thread, batch 1, this machine under its present load"}
    return summary
