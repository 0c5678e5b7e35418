"""Environment configuration: YAML under configs/env/, merged with keyword overrides, validated.

Every key, nested ones included, is checked when the config loads: an unknown key (a typo), a
wrong type or a value out of range raises ValueError naming the key path (``reward.w_effort``),
the value and what is allowed. The schema (`envs.schema`) is the list of keys; configs/env/startup.yaml
documents each of them.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path
from typing import Any, Mapping, NoReturn

from millvib_env._checks import shown, shown_path
from millvib_env._paths import config_dir
from millvib_env._yaml import load_yaml
from millvib_env.envs.disturbances import DisturbanceSettings
from millvib_env.envs.gauge import gauge_settings
from millvib_env.envs.schema import OPTIONAL_KEYS, SECTIONS, TOP_KEYS, fail, number, section
from millvib_env.loop.settings import LoopSettings
from millvib_env.params import PARAM_FIELDS, MillParams, load_preset

__all__ = ["EnvConfig", "load_env_config", "list_env_configs", "Distribution", "CONFIG_ALIASES", "ENV_VERSIONS",
           "DEFAULT_VERSION", "VersionedConfig", "cached_env_config"]

#: names kept for earlier releases: `default` is the `startup` task's episode
CONFIG_ALIASES = {"default": "startup"}
#: the environments' versions. v0: the paper's analog loop inside the plant, an ideal valve without limit
#: (configs/env/<name>.yaml). v1: the loop as commissioned: a digital controller at the control rate with
#: sensors in the loop, a servo valve with dynamics and a +-10 V amplifier (configs/env/v1/: `loop.yaml`
#: over every config, then the task's own `v1/<name>.yaml` where there is one)
ENV_VERSIONS = ("v0", "v1")
#: the version `benchmark`, `tune`, `train` and `sweep` use unless told otherwise
DEFAULT_VERSION = "v1"
#: episodes longer than this are refused before anything is allocated (the severity record is kept whole)
MAX_EPISODE_S = 60.0
#: the shortest episode that has a vibration severity: one period of the band's 10 Hz low edge
MIN_EPISODE_S = 0.1


def list_env_configs() -> list[str]:
    names = {p.stem for p in (config_dir() / "env").glob("*.yaml")}
    return sorted(names | set(CONFIG_ALIASES))


def _read(name: str | Path, _seen: tuple = ()) -> dict:
    if isinstance(name, str) and name in CONFIG_ALIASES:
        name = CONFIG_ALIASES[name]
    path = Path(name)
    if not path.suffix:
        path = config_dir() / "env" / f"{name}.yaml"
    if not path.is_file():
        raise ValueError(f"environment config {str(name)!r} not found (no file {shown_path(path)}); available: "
                         f"{list_env_configs()} or a path to a .yaml file")
    if path.resolve() in _seen:
        raise ValueError(f"environment config {shown_path(path)}: 'inherit' forms a cycle")
    data = load_yaml(path, "environment config")
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f"environment config {shown_path(path)} must be a mapping of keys, not {type(data).__name__}")
    unknown = set(data) - TOP_KEYS - {"inherit"}
    if unknown:
        raise ValueError(f"environment config {shown_path(path)}: unknown key(s) {sorted(unknown, key=repr)}; known: "
                         f"{sorted(TOP_KEYS | {'inherit'})}")
    parent = data.pop("inherit", None)
    if parent is not None:
        if not isinstance(parent, str):
            raise ValueError(f"environment config {shown_path(path)}: inherit = {shown(parent)} must be a config name")
        data = _merge(_read(parent, _seen + (path.resolve(),)), data)
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
class ObservationSettings:
    """The config's `observation` section, typed, with its defaults in one place."""

    params: bool = False  # the true c1 and Ct (privileged)
    phase: bool = False   # the pump's phase
    force: bool = False   # the load cells' force
    #: a preview: the rolling force's and the set-point's change from now to this many control samples ahead
    #: (an entry-thickness gauge upstream of the stand and the pass schedule); empty: none
    preview_samples: tuple = ()
    #: a history: the measured channels (`observation.HISTORY_CHANNELS`) as they were this many agent steps
    #: ago (what a recurrent controller would remember); empty: none
    history_samples: tuple = ()
    #: a memory of the episode so far: per time constant tau (agent steps), the measured channels' exponential
    #: moving averages and those of their squares, each updated by 1/tau a step; empty: none
    history_filters: tuple = ()
    #: the sampled loop's readings (v1) the observation carries: "previous", the sample the controller took at
    #: the period's start (one sample older than the one the agent's action is added to), or "current", the
    #: sample it takes at the period's end, which it reads together with the agent's next action (as one
    #: program on the mill's controller would); v0 observes the period's end whichever is set
    loop_sample: str = "previous"
    #: the preview's force channels as a mill measures them (`envs.gauge`): None (``exact``, the default) or a
    #: gauge's errors (``measured`` or a mapping of `envs.gauge.GaugeSettings` fields)
    preview_gauge: Any = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "preview_samples", tuple(int(k) for k in self.preview_samples))
        object.__setattr__(self, "preview_gauge", gauge_settings(self.preview_gauge))
        object.__setattr__(self, "history_samples", tuple(int(k) for k in self.history_samples))
        object.__setattr__(self, "history_filters", tuple(int(k) for k in self.history_filters))


@dataclass(frozen=True)
class RewardSettings:
    """The config's `reward` section, typed (the schema requires every key but w_offset)."""

    vibration_scale_mm_s: float  # the band velocity RMS that costs 1 (mm/s)
    tracking_scale_um: float     # the tracking RMS that costs 1 (um)
    vib_time_constant_s: float   # the observed running RMS's time constant (s)
    w_vibration: float
    w_tracking: float
    w_effort: float
    terminal_penalty: float      # subtracted once when an episode leaves the envelope
    w_offset: float = 0.0        # penalty on a relative gain action's distance from its base
    terminal_per_step: float = 0.0  # ... and this for every step the episode did not run (v1: DIVERGED_COST)


@dataclass(frozen=True)
class EnvelopeSettings:
    """The config's `envelope` section, typed: where an episode is terminated."""

    x_max_m: float       # |x| above this
    p_min_pa: float      # pL below this
    p_max_factor: float  # pL above this multiple of the supply pressure


@dataclass(frozen=True)
class InitialSettings:
    """The config's `initial` section, typed, with its defaults in one place."""

    x0_m: float = 0.0          # the start's displacement (m)
    x0_jitter_m: float = 0.0   # drawn uniformly within +- this around x0_m (m)
    settled: bool = False      # start from the settled operating point instead
    setpoint_ramp_m_s: float = 0.0  # > 0: the set-point leads back from x0 to 0 at this rate (m/s), as a
                                    # mill's position reference generator does; 0: a step (the paper's)


@dataclass(frozen=True)
class RelativeAction:
    """A relative gain action (`actions.relative`): log offsets of +-`decades` around the gains `base`."""

    base: list           # the base gains, as the config gives them (KP, KI, KD[, KPL[, KFF]])
    decades: Any = 1.0   # one number, or one per gain


@dataclass(frozen=True)
class ActionSettings:
    """The config's `actions` section, typed (the schema requires the bounds, the two ranges and the residual's
    gains; the values are the config's own, checked by the schema)."""

    kp: list                # [low, high] of each gain the gain-schedule action sets
    ki: list
    kd: list
    kpl: list
    kff: list
    u_range_v: float        # the valve action's full scale (V)
    residual_range_v: float  # the residual valve action's full scale (V)
    residual_gains: list    # the fixed controller under a residual action: KP, KI, KD[, KPL[, KFF]]
    pressure_feedback: bool = False
    force_feedforward: bool = False
    scale: str = "log"      # the gain action's scale: "log" or "linear"
    relative: RelativeAction | None = None
    #: a fixed linear feedforward added under the residual action: observation channel -> V per unit
    residual_feedforward: dict | None = None

    @classmethod
    def from_section(cls, section: Mapping) -> ActionSettings:
        rel = section.get("relative")
        fields = {k: v for k, v in section.items() if k != "relative"}
        return cls(**fields, relative=RelativeAction(**rel) if rel else None)

    def bounds(self, gain: str) -> list:
        """[low, high] of `gain` (kp, ki, kd, kpl or kff)."""
        return getattr(self, gain)


def _refuse(self, *args, **kwargs) -> NoReturn:
    raise TypeError("an EnvConfig is frozen (one config is shared by every caller that loads it): change a copy, "
                    "copy.deepcopy(config.raw), or load the config with overrides (load_env_config(name, **overrides))")


class FrozenDict(dict):
    """A config section that refuses to be changed. It is still a dict for every reader (``isinstance``, ``==``,
    JSON, pickle); a deep copy is a plain dict, yours to change."""

    __slots__ = ()
    __setitem__ = __delitem__ = __ior__ = clear = pop = popitem = setdefault = update = _refuse

    def __reduce__(self):
        return FrozenDict, (dict(self),)

    def __copy__(self) -> dict:
        return dict(self)

    def __deepcopy__(self, memo: dict) -> dict:
        return {k: copy.deepcopy(v, memo) for k, v in self.items()}


class FrozenList(list):
    """A config list that refuses to be changed (see `FrozenDict`); a deep copy is a plain list."""

    __slots__ = ()
    __setitem__ = __delitem__ = __iadd__ = __imul__ = append = extend = insert = pop = remove = clear = sort = \
        reverse = _refuse

    def __reduce__(self):
        return FrozenList, (list(self),)

    def __copy__(self) -> list:
        return list(self)

    def __deepcopy__(self, memo: dict) -> list:
        return [copy.deepcopy(v, memo) for v in self]


def frozen(value: Any) -> Any:
    """`value` with every dict and list inside it, itself included, made a `FrozenDict` or `FrozenList`."""
    if isinstance(value, dict):
        return FrozenDict({k: frozen(v) for k, v in value.items()})
    if isinstance(value, list):
        return FrozenList(frozen(v) for v in value)
    return value


@dataclass(frozen=True)
class EnvConfig:
    """Validated environment configuration (see configs/env/startup.yaml for every key). Immutable: `raw` and every
    section and list in it refuse to be changed (`FrozenDict`), since one config is shared by every caller that
    loads it (`Task.env_config`)."""

    raw: dict
    base_params: MillParams
    randomize: tuple[Distribution, ...]
    version: str = DEFAULT_VERSION

    def __post_init__(self) -> None:
        object.__setattr__(self, "raw", frozen(self.raw))

    @property
    def loop(self):
        """The sampled loop's settings (`loop.LoopSettings`), or None for the analog loop (v0)."""

        section = self.raw.get("loop")
        return None if section is None else LoopSettings.from_config(section, 1.0 / self.control_dt_s)

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

    def agent_period_s(self, mode: str) -> float:
        """The period of one environment step: the decision period for the gain schedule (`mode` "gain"), the
        control period for the valve ("valve")."""
        return self.decision_dt_s if mode == "gain" else self.control_dt_s

    def episode_steps(self, mode: str) -> int:
        """The steps of one whole episode in `mode` ("gain" or "valve"): the environment truncates after them."""
        return int(round(self.episode_s / self.agent_period_s(mode)))

    # the typed sections, each built once per config (an EnvConfig is never changed after load_env_config)
    @cached_property
    def observation(self) -> ObservationSettings:
        return ObservationSettings(**self.raw["observation"])

    @cached_property
    def reward(self) -> RewardSettings:
        return RewardSettings(**self.raw["reward"])

    @cached_property
    def envelope(self) -> EnvelopeSettings:
        return EnvelopeSettings(**self.raw["envelope"])

    @cached_property
    def initial(self) -> InitialSettings:
        return InitialSettings(**self.raw["initial"])

    @cached_property
    def actions(self) -> ActionSettings:
        return ActionSettings.from_section(self.raw["actions"])

    @cached_property
    def disturbances(self) -> DisturbanceSettings:
        return DisturbanceSettings.from_section(self.raw["disturbances"])

    def with_overrides(self, **overrides: Any) -> EnvConfig:
        """This config with keyword `overrides` merged in as `load_env_config` merges them (every key checked
        again); itself where there are none. No file is read."""
        if not overrides:
            return self
        return _validated(_merge(copy.deepcopy(self.raw), overrides), self.version)

    @property
    def pressure_feedback(self) -> bool:
        return bool(self.actions.pressure_feedback)

    @property
    def force_feedforward(self) -> bool:
        return bool(self.actions.force_feedforward)

    @property
    def log_scaled_gains(self) -> bool:
        """The gain action's scale: log (the default) or linear (`actions.scale`)."""
        return self.actions.scale == "log"


def _randomize(data: dict, base: MillParams) -> tuple[Distribution, ...]:
    spec = data.get("randomize") or {}
    if not isinstance(spec, Mapping):
        fail("randomize", spec, "must be a mapping of parameter name -> {dist, low, high}")
    dists = []
    for name, entry in spec.items():
        path = f"randomize.{name}"
        if name not in PARAM_FIELDS:
            raise ValueError(f"env config randomize: unknown plant parameter {shown(name)}; known: "
                             f"{list(PARAM_FIELDS)}")
        section(path, entry, {"dist": lambda p, v: v in ("loguniform", "uniform", "fixed") or fail(
            p, v, "one of 'loguniform', 'uniform', 'fixed'"), "low": number, "high": number}, required=("low",))
        kind = entry.get("dist", "uniform")
        lo, hi = float(entry["low"]), float(entry.get("high", entry["low"]))
        if lo > hi or (kind == "loguniform" and lo <= 0):
            fail(path, [lo, hi], "need low <= high, and low > 0 for loguniform")
        try:
            base.replace(**{name: lo})  # both ends inside MillParams' ranges
            base.replace(**{name: hi})
        except ValueError as err:
            raise ValueError(f"env config {shown_path(path)}: {err}") from None
        dists.append(Distribution(name, kind, lo, hi))
    return tuple(dists)


def _read_version(name: str | Path, version: str) -> dict:
    """A config by name or path, as environment version `version` runs it: v1 lays configs/env/v1/loop.yaml
    over a named config, then the config's own v1/<name>.yaml where there is one."""
    data = _read(name)
    if version == "v1" and isinstance(name, str) and not Path(name).suffix:
        name = CONFIG_ALIASES.get(name, name)
        data = _merge(data, _read("v1/loop"))
        if (config_dir() / "env" / "v1" / f"{name}.yaml").is_file():
            data = _merge(data, _read(f"v1/{name}"))
    return data


def load_env_config(config: str | Path | Mapping | EnvConfig | None = "startup", *, version: str = DEFAULT_VERSION,
                    **overrides: Any) -> EnvConfig:
    """Read a config by name (configs/env/<name>.yaml), path or dict and apply keyword overrides.

    Nested sections merge: ``reward={"w_effort": 0.0}`` changes one weight; ``randomize`` replaces
    the whole table. A dict config starts from `startup`. `version` (`ENV_VERSIONS`) is the
    environment's: v1 runs a named config on the loop as commissioned (configs/env/v1/). An `EnvConfig`
    (built once at the edge, e.g. a task's) is taken as it is, no file read; overrides then merge into a copy of it
    (`EnvConfig.with_overrides`).
    """
    if version not in ENV_VERSIONS:
        raise ValueError(f"version = {shown(version)} is invalid: one of {list(ENV_VERSIONS)}")
    if config is None:
        config = "startup"
    if isinstance(config, EnvConfig):
        if config.version != version:
            raise ValueError(f"config is an EnvConfig of version {shown(config.version)}, not {shown(version)}: build "
                             f"it for {shown(version)} (load_env_config(name, version={version!r}))")
        return config.with_overrides(**overrides)
    if isinstance(config, (str, Path)):
        data = _read_version(config, version)
    elif isinstance(config, Mapping):
        data = _merge(_read_version("startup", version), config)
    else:
        raise ValueError(f"config = {shown(config)} is invalid: a config name {list_env_configs()}, a path, a dict or "
                         "an EnvConfig")
    return _validated(_merge(data, overrides), version)


def _validated(data: dict, version: str) -> EnvConfig:
    """The EnvConfig of a whole config's `data`, every key checked (`envs.schema`)."""
    for key in OPTIONAL_KEYS:
        data.setdefault(key, None)
    unknown = set(data) - TOP_KEYS
    if unknown:
        raise ValueError(f"unknown env config key(s) {sorted(unknown, key=repr)}; known: {sorted(TOP_KEYS)}")
    missing = sorted(TOP_KEYS - OPTIONAL_KEYS - set(data))
    if missing:
        raise ValueError(f"env config is missing key(s) {missing}")
    _check_timing(data)
    for key, check in SECTIONS.items():
        check(key, data[key])
    if data["actions"].get("scale", "log") == "log":
        for key in ("kp", "ki", "kd", "kpl", "kff"):
            if data["actions"][key][0] <= 0:
                fail(f"actions.{key}", data["actions"][key], "log-scaled gain bounds need 0 < low < high "
                      "(or actions.scale: linear)")
    base = _base_params(data["plant"])
    cfg = EnvConfig(raw=data, base_params=base, randomize=_randomize(data, base), version=version)
    cfg.disturbances  # noqa: B018 - typed at load: a section the schema let through but no disturbance takes fails here
    return cfg


def _check_timing(data: dict) -> None:
    """episode_s, the control and decision periods and the sample rate, each checked and consistent."""
    # an episode shorter than one period of the severity band's low edge (0.1 s for 10 Hz) has no severity
    number("episode_s", data["episode_s"], lo=MIN_EPISODE_S, hi=MAX_EPISODE_S)
    for key in ("control_dt_s", "decision_dt_s"):
        number(key, data[key], lo=0.0, hi=1.0, lo_open=True)
    number("sample_rate_hz", data["sample_rate_hz"], lo=2500.0, hi=1e6)
    for key in ("control_dt_s", "decision_dt_s"):
        ratio = data[key] * data["sample_rate_hz"]
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise ValueError(f"env config {key} = {data[key]} s must be a whole number of plant samples "
                             f"(1/sample_rate_hz = {1 / data['sample_rate_hz']} s)")
    ratio = data["decision_dt_s"] / data["control_dt_s"]
    if abs(ratio - round(ratio)) > 1e-6:
        raise ValueError(f"env config decision_dt_s = {data['decision_dt_s']} must be a whole number of "
                         f"control_dt_s = {data['control_dt_s']}")
    if data["episode_s"] < data["decision_dt_s"]:
        raise ValueError(f"env config episode_s = {data['episode_s']} is shorter than one decision period "
                         f"({data['decision_dt_s']} s)")


def _base_params(plant: Any) -> MillParams:
    """The config's plant: a preset name or a mapping of MillParams fields."""
    try:
        if isinstance(plant, str):
            base = load_preset(plant)
        elif isinstance(plant, Mapping):
            base = MillParams.from_dict(plant)
        else:
            raise ValueError(f"must be a preset name or a mapping of MillParams fields, not {shown(plant)}")
    except ValueError as err:
        raise ValueError(f"env config plant: {err}") from None
    return base


def cached_env_config(name: str, version: str = DEFAULT_VERSION) -> EnvConfig:
    """The env config `name` in environment version `version` as its file has it (no overrides), read and
    validated once per process and configs folder: every caller that needs a task's plant, periods or gain
    bounds shares it (an EnvConfig is frozen; its sections are read, never written). A task's own:
    `tasks.Task.configs`."""
    return _cached_env_config(str(config_dir()), name, version)


@lru_cache(maxsize=None)
def _cached_env_config(root: str, name: str, version: str) -> EnvConfig:
    return load_env_config(name, version=version)


class VersionedConfig(Mapping[str, EnvConfig]):
    """The env config `name` in each environment version (`ENV_VERSIONS`): ``configs["v1"]`` is
    `cached_env_config(name, "v1")`, read and validated at its first use and shared. A task carries one
    (`tasks.Task.configs`), so whatever holds the task holds its configs without looking the task up again."""

    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name

    def __getitem__(self, version: str) -> EnvConfig:
        if version not in ENV_VERSIONS:
            raise ValueError(f"version = {shown(version)} is invalid: one of {list(ENV_VERSIONS)}")
        return cached_env_config(self.name, version)

    def __contains__(self, version: object) -> bool:
        return version in ENV_VERSIONS

    def get(self, version: str, default: Any = None) -> Any:
        return self[version] if version in ENV_VERSIONS else default

    def __iter__(self):
        return iter(ENV_VERSIONS)

    def __len__(self) -> int:
        return len(ENV_VERSIONS)

    def __repr__(self) -> str:
        return f"VersionedConfig({self.name!r})"

    def __reduce__(self):
        return VersionedConfig, (self.name,)
