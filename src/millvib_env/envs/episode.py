"""The draw of one episode: its plant, start and disturbances, from one episode seed.

Each episode seed spawns five children of a `SeedSequence`: the plant (randomised parameters and
the start's jitter), the disturbances, the observation's sensor noise, the sampled loop's sensors
(v1) and the measured preview's gauge (`envs.gauge`; the first ones are the same children whatever the
count). A scenario or pinned parameters
replace draws but never skip them, so the other streams stay the same.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from millvib_env._checks import as_float, shown
from millvib_env.envs.config import EnvConfig
from millvib_env.envs.disturbances import EpisodeProfile, check_profile
from millvib_env.envs.scenarios import get_scenario
from millvib_env.params import PARAM_FIELDS, MillParams
from millvib_env.plant.model import initial_state, settled_state

__all__ = ["Episode", "draw_episode", "check_reset_options", "RESET_OPTIONS"]

RESET_OPTIONS = ("params", "scenario", "x0")


@dataclass
class Episode:
    params: MillParams
    profile: EpisodeProfile
    y0: np.ndarray
    x0: float
    scenario: str | None
    noise_rng: np.random.Generator
    loop_rng: np.random.Generator
    #: the measured preview's stream (`envs.gauge`), a generator made only where the preview is measured
    gauge_seed: np.random.SeedSequence


def check_reset_options(options: Mapping | None, config: EnvConfig) -> dict:
    """Validated reset options (ValueError naming the option otherwise)."""
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise ValueError(f"reset options = {shown(options)} is invalid: a dict with keys {list(RESET_OPTIONS)}")
    unknown = set(options) - set(RESET_OPTIONS)
    if unknown:
        raise ValueError(f"unknown reset option(s) {sorted(unknown, key=repr)}: use "
                         f"{', '.join(map(repr, RESET_OPTIONS))}")
    out = dict(options)
    params = out.get("params")
    if params is not None:
        if not isinstance(params, Mapping):
            raise ValueError(f"reset option params = {shown(params)} is invalid: a dict of plant parameters")
        bad = set(params) - set(PARAM_FIELDS)
        if bad:
            raise ValueError(f"reset option params: unknown plant parameter(s) {sorted(bad)}; known: "
                             f"{list(PARAM_FIELDS)}")
        for k, v in params.items():
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise ValueError(f"reset option params.{k} = {shown(v)} is invalid: must be a number")
        config.base_params.replace(**dict(params))  # range checks (MillParams refuses a number beyond a float)
    scenario = out.get("scenario")
    if scenario is not None and not isinstance(scenario, str):
        raise ValueError(f"reset option scenario = {shown(scenario)} is invalid: a scenario name")
    x0 = out.get("x0")
    if x0 is not None:
        x_max = config.envelope.x_max_m
        if isinstance(x0, bool) or not isinstance(x0, (int, float, np.floating, np.integer)) \
                or not math.isfinite(as_float(x0)) or abs(as_float(x0)) >= x_max:
            raise ValueError(f"reset option x0 = {shown(x0)} m is invalid: a finite displacement with |x0| < "
                             f"envelope.x_max_m = {x_max} m")
    return out


def draw_episode(config: EnvConfig, disturbances: list, episode_seed: int, n_ctrl: int,
                 options: dict[str, Any], n_builtin: int | None = None) -> Episode:
    """Draw the episode of `episode_seed` (options already checked by `check_reset_options`). The first
    `n_builtin` of `disturbances` are the config's (default: all), the rest a user's (`extra_disturbances`)."""
    n_builtin = len(disturbances) if n_builtin is None else n_builtin
    plant_ss, dist_ss, noise_ss, loop_ss, gauge_ss = np.random.SeedSequence(episode_seed).spawn(5)
    plant_rng, dist_rng = np.random.default_rng(plant_ss), np.random.default_rng(dist_ss)
    initial = config.initial
    pinned: dict[str, float] = {}
    x0, jitter, settled = float(initial.x0_m), float(initial.x0_jitter_m), bool(initial.settled)
    scenario = options.get("scenario")
    if scenario is not None:

        sc = get_scenario(scenario)
        # a scenario is a fixed plant: the config's base plant plus its own changes
        pinned.update({d.name: getattr(config.base_params, d.name) for d in config.randomize})
        pinned.update(sc.params)
        x0, jitter, settled = sc.x0_m, 0.0, False
        if sc.quiet:
            disturbances = []
    if options.get("params"):
        pinned.update({k: float(v) for k, v in options["params"].items()})
    draws = {d.name: d.sample(plant_rng) for d in config.randomize}  # always drawn: same stream
    draws.update(pinned)
    params = config.base_params.replace(**draws)
    if options.get("x0") is not None:
        x0, jitter, settled = float(options["x0"]), 0.0, False
    x0 = x0 + (plant_rng.uniform(-jitter, jitter) if jitter else 0.0)

    profile = EpisodeProfile(n_ctrl, config.control_dt_s)
    for k, d in enumerate(disturbances):
        d.apply(dist_rng, profile, params)
        if k >= n_builtin:  # a user's disturbance: what it wrote is checked (the built-in ones write finite values)
            check_profile(profile, n_ctrl, d)
    rate = initial.setpoint_ramp_m_s
    if rate > 0 and x0 != 0.0:  # the reference generator leads the set-point from x0 back to 0
        t = np.arange(profile.n) * profile.dt
        profile.xd += math.copysign(1.0, x0) * np.maximum(abs(x0) - rate * t, 0.0)
    if settled:
        y0 = settled_state(params, xd=float(profile.xd[0]), dFL=float(profile.dFL[0]))
        x0 = float(y0[0])
    else:
        y0 = initial_state(params, x0=x0)
    return Episode(params, profile, y0, x0, scenario, np.random.default_rng(noise_ss),
                   np.random.default_rng(loop_ss), gauge_ss)
