"""Environment configuration: YAML under configs/env/, merged with keyword overrides, validated.

Every key, nested ones included, is checked when the config loads: an unknown key (a typo), a
wrong type or a value out of range raises ValueError naming the key path (``reward.w_effort``),
the value and what is allowed. The schema below is the list of keys; configs/env/startup.yaml
documents each of them.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path
from typing import Any, Callable, Mapping, NoReturn

from millvib_env._checks import as_float, shown, shown_path
from millvib_env._paths import config_dir
from millvib_env._yaml import load_yaml
from millvib_env.envs.disturbances import DisturbanceSettings
from millvib_env.envs.gauge import gauge_settings
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
    unknown = set(data) - _TOP_KEYS - {"inherit"}
    if unknown:
        raise ValueError(f"environment config {shown_path(path)}: unknown key(s) {sorted(unknown, key=repr)}; known: "
                         f"{sorted(_TOP_KEYS | {'inherit'})}")
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


# --- the schema --------------------------------------------------------------------------------
def _fail(path: str, value: Any, allowed: str) -> NoReturn:
    raise ValueError(f"env config {shown_path(path)} = {shown(value)} is invalid: {allowed}")


def _number(path: str, value: Any, *, lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False,
            integer: bool = False) -> float:
    ok_type = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok_type:
        _fail(path, value, f"must be {'an integer' if integer else 'a number'}" + _bounds(lo, hi, lo_open))
    if not math.isfinite(as_float(value)) or value < lo or value > hi or (lo_open and value == lo):
        _fail(path, value, "must be finite" + _bounds(lo, hi, lo_open))
    return value


def _bounds(lo: float, hi: float, lo_open: bool) -> str:
    parts = []
    if lo > -math.inf:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi < math.inf:
        parts.append(f"<= {hi:g}")
    return (" " + " and ".join(parts)) if parts else ""


#: the farthest preview an observation may carry (control samples)
MAX_PREVIEW_SAMPLES = 400


def _increasing(path: str, value: Any, hi: int, most: int) -> list:
    """A strictly increasing list of at most `most` integers, each in [1, hi]."""
    if not isinstance(value, (list, tuple)) or len(value) > most:
        _fail(path, value, f"must be a list of at most {most} increasing integers in [1, {hi}]")
    out = [int(_number(f"{path}[{i}]", v, lo=1, hi=hi, integer=True)) for i, v in enumerate(value)]
    if any(b <= a for a, b in zip(out, out[1:])):
        _fail(path, value, "must be strictly increasing")
    return out


def _preview(path: str, value: Any) -> list:
    """Look-aheads in control samples, each in [1, MAX_PREVIEW_SAMPLES]."""
    return _increasing(path, value, MAX_PREVIEW_SAMPLES, 32)


#: what `observation.loop_sample` may say (`ObservationSettings.loop_sample`)
LOOP_SAMPLES = ("previous", "current")

#: the oldest history an observation may carry (agent steps)
MAX_HISTORY_SAMPLES = 256


def _history(path: str, value: Any) -> list:
    """Lags in agent steps, each in [1, MAX_HISTORY_SAMPLES]."""
    return _increasing(path, value, MAX_HISTORY_SAMPLES, 16)


def _gauge(path: str, value: Any) -> Any:
    """``observation.preview_gauge``: 'exact', 'measured' or a mapping of `envs.gauge.GaugeSettings` fields."""
    try:
        gauge_settings(value)
    except ValueError as err:
        raise ValueError(f"env config {err}") from None
    return value


def _bool(path: str, value: Any) -> bool:
    if not isinstance(value, bool):
        _fail(path, value, "must be true or false")
    return value


def _pair(path: str, value: Any, *, lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False,
          integer: bool = False) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        _fail(path, value, "must be a [low, high] pair")
    a = _number(f"{path}[0]", value[0], lo=lo, hi=hi, lo_open=lo_open, integer=integer)
    b = _number(f"{path}[1]", value[1], lo=lo, hi=hi, lo_open=lo_open, integer=integer)
    if a > b:
        _fail(path, value, "need low <= high")
    return a, b


def _section(path: str, value: Any, fields: Mapping[str, Callable[[str, Any], Any]], *,
             required: tuple[str, ...] = ()) -> dict:
    if not isinstance(value, Mapping):
        _fail(path, value, f"must be a mapping with keys {sorted(fields)}")
    unknown = set(value) - set(fields)
    if unknown:
        raise ValueError(f"env config {shown_path(path)}: unknown key(s) {sorted(unknown, key=repr)}; known: "
                         f"{sorted(fields)}")
    missing = [k for k in required if k not in value]
    if missing:
        raise ValueError(f"env config {shown_path(path)}: missing key(s) {missing}")
    for key, check in fields.items():
        if key in value:
            check(f"{path}.{key}", value[key])
    return dict(value)


def _optional(check: Callable[[str, Any], Any]) -> Callable[[str, Any], Any]:
    return lambda path, value: None if value is None else check(path, value)


def _pos(path, v):
    return _number(path, v, lo=0.0, lo_open=True)


def _nonneg(path, v):
    return _number(path, v, lo=0.0)


#: the largest reward weight or penalty, and the range of a reward scale: an episode's return stays finite
#: (a step's cost is at most MAX_WEIGHT x (1e4 mm/s / 1e-6)^2 ~ 1e26, far from a float's 1.8e308)
MAX_WEIGHT, SCALE_RANGE = 1.0e6, (1.0e-6, 1.0e6)


def _weight(path, v):
    return _number(path, v, lo=0.0, hi=MAX_WEIGHT)


def _scale(path, v):
    return _number(path, v, lo=SCALE_RANGE[0], hi=SCALE_RANGE[1])


def _nonneg_pair(path, v):
    return _pair(path, v, lo=0.0)


def _count_pair(path, v):
    return _pair(path, v, lo=0, hi=1000, integer=True)


_DISTURBANCES = {
    "setpoint_steps": _optional(lambda p, v: _section(p, v, {
        "count": _count_pair, "amplitude_m": lambda pp, vv: _pair(pp, vv, lo=0.0, hi=5e-3),
        "window_s": _nonneg_pair}, required=("count", "amplitude_m", "window_s"))),
    "force_steps": _optional(lambda p, v: _section(p, v, {
        "count": _count_pair, "fraction": lambda pp, vv: _pair(pp, vv, lo=0.0, hi=1.0),
        "window_s": _nonneg_pair}, required=("count", "fraction", "window_s"))),
    "eccentricity": _optional(lambda p, v: _section(p, v, {
        "amplitude_n": _nonneg_pair, "frequency_hz": lambda pp, vv: _pair(pp, vv, lo=0.0, hi=1000.0)},
        required=("amplitude_n", "frequency_hz"))),
    "sensor_noise": _optional(lambda p, v: _section(p, v, {"x_m": _nonneg, "v_m_s": _nonneg, "a_m_s2": _nonneg})),
    "delay_steps": _optional(lambda p, v: _number(p, v, lo=0, hi=100, integer=True)),
    "plant_change": _optional(lambda p, v: _section(p, v, {
        "start_s": _nonneg_pair, "duration_s": lambda pp, vv: _pair(pp, vv, lo=0.0, lo_open=True),
        "c1_factor": lambda pp, vv: _pair(pp, vv, lo=0.0, hi=1.0, lo_open=True),
        "ct_factor": lambda pp, vv: _pair(pp, vv, lo=1.0, hi=1e6),
        "kinds": lambda pp, vv: _kinds(pp, vv),
        "c1_min": _pos, "ct_max": _pos},
        required=("start_s", "duration_s", "c1_factor", "ct_factor"))),
}

_CHANGE_KINDS = ("damping", "leakage", "both")


def _kinds(path: str, value: Any) -> None:
    if not isinstance(value, list) or not value or any(k not in _CHANGE_KINDS for k in value):
        _fail(path, value, f"must be a non-empty list drawn from {list(_CHANGE_KINDS)}")


def _gain_bounds(path: str, value: Any) -> None:
    lo, hi = _pair(path, value)
    if not lo < hi:
        _fail(path, value, "need low < high")


#: what a named gain set in an env config needs (the env layer takes numbers only)
_NAMED_HINT = ("the env layer takes gains as numbers; a named gain set is resolved before it (gym.make, make_vec_env "
               "and the CLI do that; in Python: millvib_env.control.named.resolve_named_gains)")


def _feedforward(path: str, value: Any) -> None:
    """A residual's fixed feedforward: observation channel name -> volts per unit of the channel (finite)."""
    if not isinstance(value, Mapping) or not value:
        _fail(path, value, "a mapping of observation channel -> gain in V per unit of the channel (N or m), e.g. "
                           "{preview_force_8: -1.0e-5}")
    for k, g in value.items():
        if not isinstance(k, str):
            _fail(f"{path} key", k, "an observation channel's name")
        if isinstance(g, bool) or not isinstance(g, (int, float)) or not math.isfinite(as_float(g)):
            _fail(f"{path}.{k}", g, "a finite number (V per N or per m)")


def _residual_gains(path: str, value: Any) -> None:
    if isinstance(value, str):
        _fail(path, value, _NAMED_HINT)
    if not isinstance(value, (list, tuple)) or len(value) not in (3, 4, 5):
        _fail(path, value, "must be [KP, KI, KD], [KP, KI, KD, KPL] or [KP, KI, KD, KPL, KFF], each >= 0")
    for k, g in enumerate(value):
        _number(f"{path}[{k}]", g, lo=0.0)


def _relative(path: str, value: Any) -> None:
    if value is None:
        return
    _section(path, value, {"base": _base_gains, "decades": _decades}, required=("base",))


def _base_gains(path: str, value: Any) -> None:
    if isinstance(value, str):
        _fail(path, value, _NAMED_HINT)
    if not isinstance(value, (list, tuple)) or not 3 <= len(value) <= 5:
        _fail(path, value, "must be [KP, KI, KD] plus KPL and KFF where switched on, each >= 0 (> 0 where its "
                           "decades > 0)")
    for k, g in enumerate(value):
        _number(f"{path}[{k}]", g, lo=0.0)


def _decades(path: str, value: Any) -> None:
    if isinstance(value, (list, tuple)):
        for k, d in enumerate(value):
            _number(f"{path}[{k}]", d, lo=0.0, hi=6.0)
    else:
        _number(path, value, lo=0.0, hi=6.0)


def checked_gains(gains: Any, where: str, hint: str = "") -> list[float]:
    """A fixed controller's gains, checked: 3-5 finite numbers >= 0 (KP, KI, KD[, KPL[, KFF]])."""
    if not isinstance(gains, list) or not 3 <= len(gains) <= 5:
        raise ValueError(f"{where} = {shown(gains)} is invalid: a list of 3-5 gains (KP, KI, KD[, KPL[, KFF]])"
                         + (f" ({hint})" if hint else ""))
    for k, g in enumerate(gains):
        if isinstance(g, bool) or not isinstance(g, (int, float)) or not math.isfinite(as_float(g)) or g < 0:
            raise ValueError(f"{where}[{k}] = {shown(g)} is invalid: a finite number >= 0")
    return [float(g) for g in gains]


_SECTIONS: dict[str, Callable[[str, Any], Any]] = {
    "initial": lambda p, v: _section(p, v, {
        "x0_m": lambda pp, vv: _number(pp, vv, lo=-0.05, hi=0.05), "x0_jitter_m": lambda pp, vv: _number(
            pp, vv, lo=0.0, hi=0.01), "settled": _bool,
        "setpoint_ramp_m_s": lambda pp, vv: _number(pp, vv, lo=0.0, hi=10.0)}),
    "loop": _optional(lambda p, v: _section(p, v, {
        "delay_samples": lambda pp, vv: _number(pp, vv, lo=0, hi=1, integer=True),
        "derivative_filter_hz": _nonneg,
        "sensors": lambda pp, vv: _section(pp, vv, {k: _nonneg for k in (
            "position_noise_m", "position_resolution_m", "pressure_noise_pa", "pressure_cutoff_hz",
            "force_noise_n", "force_cutoff_hz")})})),
    "disturbances": lambda p, v: _section(p, v, _DISTURBANCES),
    "reward": lambda p, v: _section(p, v, {
        "vibration_scale_mm_s": _scale, "tracking_scale_um": _scale, "vib_time_constant_s": _scale,
        "w_vibration": _weight, "w_tracking": _weight, "w_effort": _weight, "w_offset": _weight,
        "terminal_penalty": _weight, "terminal_per_step": _weight},
        required=("vibration_scale_mm_s", "tracking_scale_um", "vib_time_constant_s", "w_vibration",
                  "w_tracking", "w_effort", "terminal_penalty")),
    "actions": lambda p, v: _section(p, v, {
        "kp": _gain_bounds, "ki": _gain_bounds, "kd": _gain_bounds, "kpl": _gain_bounds, "kff": _gain_bounds,
        "pressure_feedback": _bool, "force_feedforward": _bool, "relative": _relative,
        "u_range_v": _pos, "residual_range_v": _pos,
        "residual_gains": _residual_gains, "residual_feedforward": _feedforward,
        "scale": lambda pp, vv: vv in ("log", "linear") or _fail(
            pp, vv, "'log' or 'linear'")},
        required=("kp", "ki", "kd", "kpl", "kff", "u_range_v", "residual_range_v", "residual_gains")),
    "envelope": lambda p, v: _section(p, v, {
        "x_max_m": lambda pp, vv: _number(pp, vv, lo=0.0, hi=0.1, lo_open=True),
        "p_min_pa": lambda pp, vv: _number(pp, vv, hi=0.0), "p_max_factor": lambda pp, vv: _number(
            pp, vv, lo=1.0, hi=9.0, lo_open=True)},
        required=("x_max_m", "p_min_pa", "p_max_factor")),
    "observation": lambda p, v: _section(p, v, {"phase": _bool, "params": _bool, "force": _bool,
                                                "preview_samples": _preview, "history_samples": _history,
                                                "loop_sample": lambda pp, vv: vv in LOOP_SAMPLES or _fail(
                                                    pp, vv, f"one of {list(LOOP_SAMPLES)}"),
                                                "preview_gauge": _gauge}),
}

_TOP_KEYS = {"plant", "episode_s", "control_dt_s", "decision_dt_s", "sample_rate_hz", "randomize",
             *_SECTIONS}
#: top-level keys a config may leave out (their absence is the v0 behaviour)
_OPTIONAL_KEYS = {"loop"}


def _randomize(data: dict, base: MillParams) -> tuple[Distribution, ...]:
    spec = data.get("randomize") or {}
    if not isinstance(spec, Mapping):
        _fail("randomize", spec, "must be a mapping of parameter name -> {dist, low, high}")
    dists = []
    for name, entry in spec.items():
        path = f"randomize.{name}"
        if name not in PARAM_FIELDS:
            raise ValueError(f"env config randomize: unknown plant parameter {shown(name)}; known: "
                             f"{list(PARAM_FIELDS)}")
        _section(path, entry, {"dist": lambda p, v: v in ("loguniform", "uniform", "fixed") or _fail(
            p, v, "one of 'loguniform', 'uniform', 'fixed'"), "low": _number, "high": _number}, required=("low",))
        kind = entry.get("dist", "uniform")
        lo, hi = float(entry["low"]), float(entry.get("high", entry["low"]))
        if lo > hi or (kind == "loguniform" and lo <= 0):
            _fail(path, [lo, hi], "need low <= high, and low > 0 for loguniform")
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


def load_env_config(config: str | Path | Mapping | None = "startup", *, version: str = DEFAULT_VERSION,
                    **overrides: Any) -> EnvConfig:
    """Read a config by name (configs/env/<name>.yaml), path or dict and apply keyword overrides.

    Nested sections merge: ``reward={"w_effort": 0.0}`` changes one weight; ``randomize`` replaces
    the whole table. A dict config starts from `startup`. `version` (`ENV_VERSIONS`) is the
    environment's: v1 runs a named config on the loop as commissioned (configs/env/v1/).
    """
    if version not in ENV_VERSIONS:
        raise ValueError(f"version = {shown(version)} is invalid: one of {list(ENV_VERSIONS)}")
    if config is None:
        config = "startup"
    if isinstance(config, (str, Path)):
        data = _read_version(config, version)
    elif isinstance(config, Mapping):
        data = _merge(_read_version("startup", version), config)
    else:
        raise ValueError(f"config = {shown(config)} is invalid: a config name {list_env_configs()}, a path or a dict")
    data = _merge(data, overrides)
    for key in _OPTIONAL_KEYS:
        data.setdefault(key, None)
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise ValueError(f"unknown env config key(s) {sorted(unknown, key=repr)}; known: {sorted(_TOP_KEYS)}")
    missing = sorted(_TOP_KEYS - _OPTIONAL_KEYS - set(data))
    if missing:
        raise ValueError(f"env config is missing key(s) {missing}")
    _check_timing(data)
    for key, check in _SECTIONS.items():
        check(key, data[key])
    if data["actions"].get("scale", "log") == "log":
        for key in ("kp", "ki", "kd", "kpl", "kff"):
            if data["actions"][key][0] <= 0:
                _fail(f"actions.{key}", data["actions"][key], "log-scaled gain bounds need 0 < low < high "
                      "(or actions.scale: linear)")
    base = _base_params(data["plant"])
    cfg = EnvConfig(raw=data, base_params=base, randomize=_randomize(data, base), version=version)
    cfg.disturbances  # noqa: B018 - typed at load: a section the schema let through but no disturbance takes fails here
    return cfg


def _check_timing(data: dict) -> None:
    """episode_s, the control and decision periods and the sample rate, each checked and consistent."""
    # an episode shorter than one period of the severity band's low edge (0.1 s for 10 Hz) has no severity
    _number("episode_s", data["episode_s"], lo=MIN_EPISODE_S, hi=MAX_EPISODE_S)
    for key in ("control_dt_s", "decision_dt_s"):
        _number(key, data[key], lo=0.0, hi=1.0, lo_open=True)
    _number("sample_rate_hz", data["sample_rate_hz"], lo=2500.0, hi=1e6)
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
