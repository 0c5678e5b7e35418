"""What a batch of episodes is, fixed when the engine is made: `CoreSettings`, apart from the engine's per-step state.

As gymnax keeps a frozen `EnvParams` apart from its `EnvState`, `envs.core.MillVibCore` holds its settings in one
frozen object (`core.settings`) and its episodes' state (the plants, the loop's and the records' arrays, the
generators) in its own arrays. The settings are read, never changed: the number of environments, the engine's mode,
the config, the episode's clock (the agent's period, its control and plant samples, the episode's length), the
action's range and the envelope. `core_settings` checks the engine's arguments and builds them, and refuses a batch
whose records would not fit in memory before anything is allocated.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from millvib_env._checks import as_float, shown
from millvib_env.envs.actions import GainMap
from millvib_env.envs.config import EnvConfig
from millvib_env.loop.settings import LoopSettings
from millvib_env.params import PIDGains
from millvib_env.plant.integrate import DEFAULT_RTOL_FAST, MAX_STEPS_PER_SECOND
from millvib_env.plant.model import NAUX, NY

__all__ = ["CoreSettings", "core_settings", "MAX_BATCH_BYTES"]

#: a batch whose arrays would exceed this is refused before allocation (ValueError)
MAX_BATCH_BYTES = 4 * 2**30


@dataclass(frozen=True)
class CoreSettings:
    """A batch's settings (module docstring). Built by `core_settings`."""

    #: the environments advanced together
    n: int
    #: "gain" (the agent sets the PID's gains) or "valve" (it commands the valve)
    mode: str
    #: a valve action added to the loop's own PID command (a residual), not the whole command
    residual: bool
    #: the environment's config, built once at the edge
    cfg: EnvConfig
    #: the sampled loop (v1: a digital controller at the control rate, sensors in the loop), or None for the
    #: paper's analog loop inside the plant (v0)
    loop: LoopSettings | None
    #: the loop's readings the observation carries: the sample the controller took at the period's start
    #: (False, v1's default: one sample older than the one the agent's action joins) or the one it takes at the
    #: period's end, with the agent's action (True: `observation.loop_sample` "current")
    fresh: bool
    #: the agent's period (s), its control samples and its plant samples (per control sample, per period)
    period_s: float
    n_sub: int
    spp: int
    n_samp: int
    #: the plant's sample time (s)
    dt_sample: float
    #: an episode's agent steps, control samples and samples of its trace (with the one at t = 0)
    max_steps: int
    n_ctrl: int
    trace_samples: int
    #: the action: the gain map (gain mode), its width, the volts of action 1 and the fixed feedforward's limit (V)
    gain_map: GainMap
    act_dim: int
    u_range: float
    ff_limit: float
    #: the loop's own PID under a valve action (a residual's base)
    residual_gains: PIDGains
    #: the privileged and measured channels the observation carries
    observe_params: bool
    observe_phase: bool
    observe_force: bool
    #: the measured preview's settings (`envs.gauge`), or None where the preview is exact or there is none
    gauge: Any
    #: the envelope: the largest displacement (m), the lowest chamber pressure (Pa), the highest as a multiple of
    #: the supply pressure
    x_max: float
    p_min: float
    p_max_factor: float
    #: the fast integrator's relative tolerance and its step budget per period
    rtol: float
    max_kernel_steps: int


def _flag(name: str, flag: Any) -> None:
    if flag is not None and not isinstance(flag, (bool, np.bool_)):
        raise ValueError(f"{name} = {shown(flag)} is invalid: must be True or False")


def core_settings(n: int, mode: str, config: EnvConfig, *, residual: bool = False,
                  observe_params: bool | None = None, observe_phase: bool | None = None) -> CoreSettings:
    """The settings of `n` environments of engine `mode` ("gain" or "valve") on `config`; a ValueError of one line
    for an argument out of range or a batch whose episode records would exceed `MAX_BATCH_BYTES`."""
    if mode not in ("gain", "valve"):
        raise ValueError(f"mode = {shown(mode)} is invalid: 'gain' or 'valve'")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n_envs = {shown(n)} is invalid: an integer >= 1")
    for name, flag in (("residual", residual), ("observe_params", observe_params), ("observe_phase", observe_phase)):
        _flag(name, flag)
    n = int(n)
    residual = bool(residual and mode == "valve")
    seen, acts, env = config.observation, config.actions, config.envelope
    period_s = config.agent_period_s(mode)
    n_sub = int(round(period_s / config.control_dt_s))
    spp = int(round(config.control_dt_s * config.sample_rate_hz))
    n_samp = n_sub * spp
    max_steps = config.episode_steps(mode)
    n_ctrl = max_steps * n_sub
    n_trace = max_steps * n_samp + 1
    need = 8 * n * (n_trace + 2 * n_ctrl + 2 * (n_samp + 1) * (NY + NAUX))
    if need > MAX_BATCH_BYTES:
        raise ValueError(f"n_envs = {shown(n)} with episode_s = {config.episode_s} s would need "
                         f"{as_float(need) / 2**30:.1f} GiB of episode records; allowed up to "
                         f"{MAX_BATCH_BYTES / 2**30:.0f} GiB: use fewer environments or shorter episodes")
    gain_map = GainMap.from_config(config)
    return CoreSettings(
        n=n, mode=mode, residual=residual, cfg=config, loop=config.loop,
        fresh=config.loop is not None and seen.loop_sample == "current",
        period_s=period_s, n_sub=n_sub, spp=spp, n_samp=n_samp, dt_sample=1.0 / config.sample_rate_hz,
        max_steps=max_steps, n_ctrl=n_ctrl, trace_samples=n_trace,
        gain_map=gain_map, act_dim=gain_map.dim if mode == "gain" else 1,
        u_range=float(acts.residual_range_v if residual else acts.u_range_v), ff_limit=float(acts.u_range_v),
        residual_gains=PIDGains(*acts.residual_gains),
        observe_params=bool(seen.params if observe_params is None else observe_params),
        observe_phase=bool(seen.phase if observe_phase is None else observe_phase),
        observe_force=bool(seen.force), gauge=seen.preview_gauge if seen.preview_samples else None,
        x_max=env.x_max_m, p_min=env.p_min_pa, p_max_factor=env.p_max_factor,
        rtol=DEFAULT_RTOL_FAST, max_kernel_steps=int(MAX_STEPS_PER_SECOND * period_s) + 1000)
