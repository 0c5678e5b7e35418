"""Episode disturbances as small composable classes, built by a factory from configuration.

Each disturbance draws its episode realisation from its own generator (a child of the episode's
SeedSequence) and writes into the episode's profile arrays on the control grid (one value per
control period): set-point xd (m) and rolling-force offset dFL (N). Roll eccentricity is a
sinusoidal force whose amplitude, frequency and phase are drawn per episode; a plant change moves
c1 and Ct during the episode (`PlantChange`, integrated by the plant's own equations); sensor noise
and delay act on the observation. The config's keys are checked in `envs.config`.

A user's own disturbance is any object with the `Disturbance` method `apply(rng, profile, params)`, given to an
environment as ``extra_disturbances=[...]``: it runs after the config's disturbances, from the same stream, so
the config's draws are the same with it or without it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import math

import numpy as np

from millvib_env._checks import shown
from millvib_env.params import MillParams
from millvib_env.plant.model import PlantChange

__all__ = ["EpisodeProfile", "Disturbance", "SetpointSteps", "ForceSteps", "Eccentricity", "ParameterChange",
           "SensorNoise", "build_disturbances", "user_disturbances", "check_profile"]


@dataclass
class EpisodeProfile:
    """What one episode's disturbances do, on the control grid of `n` periods of `dt` seconds."""

    n: int
    dt: float
    xd: np.ndarray = field(init=False)
    dFL: np.ndarray = field(init=False)
    ecc_amp_n: float = 0.0
    ecc_omega: float = 0.0
    ecc_phase: float = 0.0
    change: PlantChange | None = None
    events: list = field(default_factory=list)

    def __post_init__(self):
        self.xd = np.zeros(self.n)
        self.dFL = np.zeros(self.n)


@runtime_checkable
class Disturbance(Protocol):
    """What a disturbance does at each reset: draw this episode's realisation from `rng` (the episode's
    disturbance stream: the config's disturbances draw first, then a user's, in order) and write it into
    `profile` (`EpisodeProfile`): the set-point `profile.xd` (m) and the rolling-force offset `profile.dFL` (N),
    one finite value per control period of `profile.dt` s (change them in place: their length is the episode's),
    and an event ``(kind, time_s, value)`` in `profile.events`, which the reset's info reports. `params` is the
    episode's plant. The built-in ones below are `Disturbance`s; a user passes their own to any environment as
    ``extra_disturbances=[...]`` (docs/environments.md, "Your own disturbance")."""

    def apply(self, rng: np.random.Generator, profile: EpisodeProfile, params: MillParams) -> None: ...


def user_disturbances(items: Any) -> list:
    """An environment's ``extra_disturbances``, checked: None or a list (or tuple) of `Disturbance` objects."""
    what = "a list of objects with an apply(rng, profile, params) method (envs.disturbances.Disturbance)"
    if items is None:
        return []
    if not isinstance(items, (list, tuple)):
        raise ValueError(f"extra_disturbances = {shown(items)} is invalid: {what}")
    for k, d in enumerate(items):
        if not callable(getattr(d, "apply", None)):
            raise ValueError(f"extra_disturbances[{k}] = {shown(d)} is invalid: {what}")
    return list(items)


def check_profile(profile: EpisodeProfile, n: int, who: Any) -> None:
    """After `who` applied itself: the profile's set-point and force are still n finite values each."""
    for name in ("xd", "dFL"):
        values = getattr(profile, name)
        if not isinstance(values, np.ndarray) or values.shape != (n,) or not np.all(np.isfinite(values)):
            raise ValueError(f"disturbance {shown(who)} left profile.{name} invalid: {n} finite values (change "
                             "the array in place)")


def _range(pair) -> tuple[float, float]:
    lo, hi = pair
    return float(lo), float(hi)


def _count(pair) -> tuple[int, int]:
    lo, hi = pair
    return int(lo), int(hi)


def _step_times(rng, count: tuple[int, int], window_s: tuple[float, float], profile: EpisodeProfile) -> list[int]:
    n = int(rng.integers(count[0], count[1] + 1))
    t_lo, t_hi = window_s
    t_hi = min(t_hi, profile.n * profile.dt)
    times = np.sort(rng.uniform(t_lo, t_hi, n)) if n and t_hi > t_lo else np.array([])
    return [min(profile.n - 1, int(t / profile.dt)) for t in times]


@dataclass(frozen=True)
class SetpointSteps:
    """Gauge corrections: `count` (a range) set-point steps of +-`amplitude_m` (a range, m) at times in
    `window_s` (s)."""

    count: tuple[int, int]
    amplitude_m: tuple[float, float]
    window_s: tuple[float, float]

    def apply(self, rng, profile: EpisodeProfile, params) -> None:
        lo, hi = self.amplitude_m
        for k in _step_times(rng, self.count, self.window_s, profile):
            step = rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi)
            profile.xd[k:] += step
            profile.events.append(("setpoint", k * profile.dt, float(step)))


@dataclass(frozen=True)
class ForceSteps:
    """Entry-thickness or hardness changes: `count` rolling-force steps of +-`fraction` x FL at times in
    `window_s` (s)."""

    count: tuple[int, int]
    fraction: tuple[float, float]
    window_s: tuple[float, float]

    def apply(self, rng, profile: EpisodeProfile, params) -> None:
        lo, hi = self.fraction
        for k in _step_times(rng, self.count, self.window_s, profile):
            step = rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi) * params.FL
            profile.dFL[k:] += step
            profile.events.append(("force", k * profile.dt, float(step)))


@dataclass(frozen=True)
class Eccentricity:
    """Roll eccentricity: a force F sin(2 pi f t + phase), amplitude (N) and frequency (Hz) drawn per episode from
    their ranges."""

    amplitude_n: tuple[float, float]
    frequency_hz: tuple[float, float]

    def apply(self, rng, profile: EpisodeProfile, params) -> None:
        a_lo, a_hi = self.amplitude_n
        f_lo, f_hi = self.frequency_hz
        profile.ecc_amp_n = float(rng.uniform(a_lo, a_hi))
        profile.ecc_omega = float(2 * np.pi * rng.uniform(f_lo, f_hi))
        profile.ecc_phase = float(rng.uniform(0, 2 * np.pi))
        profile.events.append(("eccentricity", 0.0, {"amplitude_n": profile.ecc_amp_n,
                                                     "frequency_hz": profile.ecc_omega / (2 * np.pi)}))


@dataclass(frozen=True)
class ParameterChange:
    """The damping falls and/or the leakage rises during the episode (a `PlantChange`).

    Start time and duration uniform, factors log-uniform; the final values are kept within the
    paper's ranges (c1 >= c1_min, Ct <= ct_max); which of damping, leakage or both changes is
    drawn from `kinds` with equal odds.
    """

    start_s: tuple[float, float]
    duration_s: tuple[float, float]
    c1_factor: tuple[float, float]
    ct_factor: tuple[float, float]
    kinds: tuple[str, ...] = ("both",)  # "damping", "leakage" and/or "both"
    c1_min: float = 0.0                 # c1 never falls below this (N s/m)
    ct_max: float = math.inf            # Ct never rises above this (m^3/(s Pa))

    def apply(self, rng, profile: EpisodeProfile, params) -> None:
        kinds = list(self.kinds)
        kind = kinds[int(rng.integers(len(kinds)))]
        t0 = float(rng.uniform(*self.start_s))
        duration = float(rng.uniform(*self.duration_s))
        lo, hi = self.c1_factor
        f_c1 = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        lo, hi = self.ct_factor
        f_ct = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        f_c1 = max(f_c1, self.c1_min / params.c1) if kind != "leakage" else 1.0
        f_ct = min(f_ct, self.ct_max / params.Ct) if kind != "damping" else 1.0
        profile.change = PlantChange(t0, duration, min(f_c1, 1.0), max(f_ct, 1.0))
        profile.events.append(("plant_change", t0, {"kind": kind, "duration_s": duration,
                                                    "c1_factor": profile.change.c1_factor,
                                                    "ct_factor": profile.change.ct_factor}))


@dataclass(frozen=True)
class SensorNoise:
    """Gaussian measurement noise on the observed position (m), velocity (m/s), acceleration (m/s^2)."""

    x_m: float = 0.0
    v_m_s: float = 0.0
    a_m_s2: float = 0.0

    def sample(self, rng, n: int) -> np.ndarray:
        return rng.normal(0.0, 1.0, (n, 3)) * np.array([self.x_m, self.v_m_s, self.a_m_s2])


def _steps(cls, size: str):
    return lambda s: cls(_count(s["count"]), _range(s[size]), _range(s["window_s"]))


def _change(s) -> ParameterChange:
    return ParameterChange(_range(s["start_s"]), _range(s["duration_s"]), _range(s["c1_factor"]),
                           _range(s["ct_factor"]), tuple(s.get("kinds") or ["both"]), float(s.get("c1_min", 0.0)),
                           float(s.get("ct_max", math.inf)))


#: each profile disturbance of the config's section, typed from its (schema-checked) entry, in the order they draw
_PROFILE_KINDS = {"setpoint_steps": _steps(SetpointSteps, "amplitude_m"), "force_steps": _steps(ForceSteps, "fraction"),
                  "eccentricity": lambda s: Eccentricity(_range(s["amplitude_n"]), _range(s["frequency_hz"])),
                  "plant_change": _change}


@dataclass(frozen=True)
class DisturbanceSettings:
    """The config's ``disturbances`` section, typed (`EnvConfig.disturbances`, built once at load): the profile
    disturbances in the order they draw (frozen, so one config's are shared by every environment), the sensor
    noise, and the observation's delay in agent steps."""

    profile: tuple = ()
    sensor_noise: SensorNoise | None = None
    delay_steps: int = 0

    @classmethod
    def from_section(cls, spec) -> DisturbanceSettings:
        items, noise, delay = build_disturbances(spec)
        return cls(tuple(items), noise, delay)


def build_disturbances(spec) -> tuple[list, SensorNoise | None, int]:
    """From the config's `disturbances` section: (profile disturbances, sensor noise, delay steps)."""
    items = []
    for key, build in _PROFILE_KINDS.items():
        if spec.get(key):
            items.append(build(spec[key]))
    unknown = set(spec) - set(_PROFILE_KINDS) - {"sensor_noise", "delay_steps"}
    if unknown:
        raise ValueError(f"unknown disturbance(s) {sorted(unknown, key=repr)}; known: {sorted(_PROFILE_KINDS)}, "
                         "sensor_noise, delay_steps")
    noise = SensorNoise(**spec["sensor_noise"]) if spec.get("sensor_noise") else None
    return items, noise, int(spec.get("delay_steps") or 0)
