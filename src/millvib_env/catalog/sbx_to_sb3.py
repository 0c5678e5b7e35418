"""An sbx (JAX) SAC as an SB3 (PyTorch) SAC: the same networks, weight for weight.

sbx's SAC and SB3's build the same networks for a flat observation: the actor an MLP (ReLU) with a mean head and a
log-std head, the squashed Gaussian's mode tanh(mean) as the deterministic action; the critics MLPs on the
observation and the action, side by side (sbx stacks them in one vmapped module). A Dense kernel (in, out) is a
Linear weight (out, in) transposed. `sb3_sac_from_sbx` copies the actor, both critics and their targets, and the
entropy coefficient into a new SB3 SAC, which then runs (`predict`, ONNX export: `catalog.export`) without JAX;
its actions equal the sbx model's within float32 rounding (a test compares them). The replay buffer and the
optimisers' state are not carried over: the copy is for running the policy, not for resuming its training.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["sb3_sac_from_sbx"]


def _dense(params: dict, name: str) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(params[name]["kernel"], dtype=np.float32), np.asarray(params[name]["bias"], dtype=np.float32)


def _linears(module) -> list:
    import torch

    return [m for m in module if isinstance(m, torch.nn.Linear)]


def _copy(linear, kernel: np.ndarray, bias: np.ndarray) -> None:
    import torch

    if tuple(linear.weight.shape) != kernel.T.shape:
        raise ValueError(f"the sbx layer of shape {kernel.shape} does not fit SB3's {tuple(linear.weight.shape)}")
    linear.weight.copy_(torch.as_tensor(kernel.T.copy()))
    linear.bias.copy_(torch.as_tensor(bias))


def sb3_sac_from_sbx(model: Any):
    """A new SB3 `SAC` with the networks of sbx SAC `model` (module docstring). Refused in one line for another
    algorithm or a network SB3's SAC does not build (layer norm, dropout, another activation)."""
    import gymnasium as gym
    import torch
    from stable_baselines3 import SAC

    policy: Any = getattr(model, "policy", None)
    actor, critic = getattr(policy, "actor", None), getattr(policy, "qf", None)
    if type(model).__name__ != "SAC" or not type(model).__module__.startswith("sbx") or actor is None or critic is None:
        raise ValueError(f"model = {type(model).__name__} is invalid: an sbx SAC")
    relu = all(getattr(net.activation_fn, "__name__", "") == "relu" for net in (actor, critic))
    if getattr(critic, "use_layer_norm", False) or getattr(critic, "dropout_rate", 0.0) or not relu:
        raise ValueError("the sbx SAC's networks (layer norm, dropout or an activation other than ReLU) have no "
                         "SB3 SAC counterpart")

    class _Spaces(gym.Env):  # SB3 builds its networks from an environment's spaces; this one is never stepped
        observation_space, action_space = model.observation_space, model.action_space

    sb3 = SAC("MlpPolicy", _Spaces(), buffer_size=1, device="cpu", gamma=model.gamma, tau=model.tau,
              policy_kwargs={"net_arch": {"pi": list(actor.net_arch), "qf": list(critic.net_arch)},
                             "n_critics": int(critic.n_critics), "activation_fn": torch.nn.ReLU})
    with torch.no_grad():
        params = policy.actor_state.params["params"]
        hidden = _linears(sb3.actor.latent_pi)
        for i, linear in enumerate(hidden):
            _copy(linear, *_dense(params, f"Dense_{i}"))
        _copy(sb3.actor.mu, *_dense(params, f"Dense_{len(hidden)}"))
        _copy(sb3.actor.log_std, *_dense(params, f"Dense_{len(hidden) + 1}"))
        critics = ((policy.qf_state.params, sb3.critic), (policy.qf_state.target_params, sb3.critic_target))
        for source, target in critics:
            stacked = source["params"]["VmapContinuousCritic_0"]
            for q, net in enumerate(target.q_networks):
                for j, linear in enumerate(_linears(net)):
                    kernel, bias = _dense(stacked, f"Dense_{j}")
                    _copy(linear, kernel[q], bias[q])
        state = getattr(model, "ent_coef_state", None)
        log_ent_coef: Any = getattr(sb3, "log_ent_coef", None)  # a learned coefficient ("auto"), else None
        if state is not None and log_ent_coef is not None:
            log_ent = state.params.get("log_ent_coef", state.params.get("params", {}).get("log_ent_coef"))
            if log_ent is not None:
                value = torch.as_tensor(np.asarray(log_ent, dtype=np.float32))
                log_ent_coef.copy_(value.reshape(log_ent_coef.shape))
    sb3.policy.set_training_mode(False)
    return sb3
