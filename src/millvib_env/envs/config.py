"""Environment configuration: YAML under configs/env/, merged with keyword overrides, validated."""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from millvib_env._yaml import load_yaml

from millvib_env._paths import config_dir
from millvib_env.params import PARAM_FIELDS, MillParams, load_preset

__all__ = ["EnvConfig", "load_env_config", "list_env_configs", "Distribution"]

_TOP_KEYS = {"plant", "episode_s", "control_dt_s", "decision_dt_s", "sample_rate_hz", "randomize", "initial",
             "disturbances", "reward", "actions", "envelope", "observation"}


def list_env_configs() -> list[str]:
    return sorted(p.stem for p in (config_dir() / "env").glob("*.yaml"))


def _read(name: str | Path) -> dict:
    path = Path(name)
    if not path.suffix:
        path = config_dir() / "env" / f"{name}.yaml"
    if not path.exists():
        raise ValueError(f"environment config {str(name)!r} not found; available: {list_env_configs()}")
    data = load_yaml(path) or {}
    parent = data.pop("inherit", None)
    if parent:
        data = _merge(_read(parent), data)
    return data


def _merge(base: dict, over: Mapping) -> dict:
    out = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), dict) and key != "randomize":
            out[key] = _merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


@dataclass(frozen=True)
class Distribution:
    """A randomised plant parameter: 'loguniform' or 'uniform' over [low, high], or 'fixed'."""

    name: str
    dist: str
    low: float
    high: float

    def sample(self, rng) -> float:
        if self.dist == "loguniform":
            return float(math.exp(rng.uniform(math.log(self.low), math.log(self.high))))
        if self.dist == "uniform":
            return float(rng.uniform(self.low, self.high))
        return float(self.low)


@dataclass(frozen=True)
class EnvConfig:
    """Validated environment configuration (see configs/env/default.yaml for every key)."""

    raw: dict
    base_params: MillParams
    randomize: tuple[Distribution, ...]

    def __getitem__(self, key: str) -> Any:
        return self.raw[key]

    @property
    def episode_s(self) -> float:
        return float(self.raw["episode_s"])

    @property
    def control_dt_s(self) -> float:
        return float(self.raw["control_dt_s"])

    @property
    def decision_dt_s(self) -> float:
        return float(self.raw["decision_dt_s"])

    @property
    def sample_rate_hz(self) -> float:
        return float(self.raw["sample_rate_hz"])


def _positive(cfg: dict, key: str) -> float:
    value = cfg[key]
    if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"env config {key} = {value!r} is invalid: must be a finite number > 0")
    return float(value)


def load_env_config(config: str | Path | Mapping | None = "default", **overrides: Any) -> EnvConfig:
    """Read a config by name (configs/env/<name>.yaml), path or dict and apply keyword overrides.

    Nested sections merge: ``reward={"w_effort": 0.0}`` changes one weight; ``randomize`` replaces
    the whole table.
    """
    if config is None:
        config = "default"
    data = _read(config) if isinstance(config, (str, Path)) else _merge(_read("default"), config)
    data = _merge(data, overrides)
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise ValueError(f"unknown env config key(s) {sorted(unknown)}; known: {sorted(_TOP_KEYS)}")
    for key in ("episode_s", "control_dt_s", "decision_dt_s", "sample_rate_hz"):
        _positive(data, key)
    for key in ("control_dt_s", "decision_dt_s"):
        ratio = data[key] * data["sample_rate_hz"]
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise ValueError(f"env config {key} = {data[key]} s must be a whole number of plant samples "
                             f"(1/sample_rate_hz = {1 / data['sample_rate_hz']} s)")
    ratio = data["decision_dt_s"] / data["control_dt_s"]
    if abs(ratio - round(ratio)) > 1e-6:
        raise ValueError(f"decision_dt_s = {data['decision_dt_s']} must be a whole number of control_dt_s "
                         f"= {data['control_dt_s']}")
    if data["sample_rate_hz"] < 2500:
        raise ValueError(f"sample_rate_hz = {data['sample_rate_hz']} is invalid: >= 2500 Hz is needed for the "
                         "1 kHz severity band")
    base = load_preset(data["plant"]) if isinstance(data["plant"], str) else MillParams.from_dict(data["plant"])
    dists = []
    for name, spec in (data.get("randomize") or {}).items():
        if name not in PARAM_FIELDS:
            raise ValueError(f"randomize: unknown plant parameter {name!r}; known: {list(PARAM_FIELDS)}")
        kind = spec.get("dist", "uniform")
        lo, hi = float(spec["low"]), float(spec.get("high", spec["low"]))
        if kind not in ("loguniform", "uniform", "fixed"):
            raise ValueError(f"randomize.{name}.dist = {kind!r} is invalid: loguniform, uniform or fixed")
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi) or (kind == "loguniform" and lo <= 0):
            raise ValueError(f"randomize.{name}: [{lo}, {hi}] is invalid (need low <= high, > 0 for loguniform)")
        base.replace(**{name: lo})  # validates both ends against MillParams' ranges
        base.replace(**{name: hi})
        dists.append(Distribution(name, kind, lo, hi))
    for key in ("kp", "ki", "kd"):
        lo, hi = data["actions"][key]
        if not (0 < lo < hi and math.isfinite(hi)):
            raise ValueError(f"actions.{key} = {[lo, hi]} is invalid: need 0 < low < high (log-scaled)")
    for key in ("u_range_v", "residual_range_v"):
        _positive(data["actions"], key)
    for key in ("vibration_scale_mm_s", "tracking_scale_um", "vib_time_constant_s"):
        _positive(data["reward"], key)
    for key in ("w_vibration", "w_tracking", "w_effort", "terminal_penalty"):
        value = data["reward"][key]
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ValueError(f"reward.{key} = {value!r} is invalid: must be finite and >= 0")
    delay = data["disturbances"].get("delay_steps") or 0
    if not (isinstance(delay, int) and 0 <= delay <= 100):
        raise ValueError(f"disturbances.delay_steps = {delay!r} is invalid: an integer in [0, 100]")
    return EnvConfig(raw=data, base_params=base, randomize=tuple(dists))
