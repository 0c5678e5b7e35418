"""The environment config's schema: every key of configs/env/*.yaml with its check (`envs.config` loads a config
and runs them). A check raises ValueError naming the key path (``reward.w_effort``), the value and what is allowed;
configs/env/startup.yaml documents each key."""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping, NoReturn

from millvib_env._checks import as_float, shown, shown_path
from millvib_env.envs.gauge import gauge_settings

__all__ = ["checked_gains", "fail", "number", "section", "SECTIONS", "TOP_KEYS", "OPTIONAL_KEYS",
           "MAX_PREVIEW_SAMPLES", "MAX_HISTORY_SAMPLES", "MAX_HISTORY_FILTER",
           "LOOP_SAMPLES"]


# --- the checks --------------------------------------------------------------------------------
def fail(path: str, value: Any, allowed: str) -> NoReturn:
    raise ValueError(f"env config {shown_path(path)} = {shown(value)} is invalid: {allowed}")


def number(path: str, value: Any, *, lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False,
            integer: bool = False) -> float:
    ok_type = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok_type:
        fail(path, value, f"must be {'an integer' if integer else 'a number'}" + _bounds(lo, hi, lo_open))
    if not math.isfinite(as_float(value)) or value < lo or value > hi or (lo_open and value == lo):
        fail(path, value, "must be finite" + _bounds(lo, hi, lo_open))
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
        fail(path, value, f"must be a list of at most {most} increasing integers in [1, {hi}]")
    out = [int(number(f"{path}[{i}]", v, lo=1, hi=hi, integer=True)) for i, v in enumerate(value)]
    if any(b <= a for a, b in zip(out, out[1:])):
        fail(path, value, "must be strictly increasing")
    return out


def _preview(path: str, value: Any) -> list:
    """Look-aheads in control samples, each in [1, MAX_PREVIEW_SAMPLES]."""
    return _increasing(path, value, MAX_PREVIEW_SAMPLES, 32)


#: what `observation.loop_sample` may say (`ObservationSettings.loop_sample`)
LOOP_SAMPLES = ("previous", "current")

#: the oldest history an observation may carry (agent steps)
MAX_HISTORY_SAMPLES = 256
#: the longest time constant of a history filter (agent steps; `ObservationSettings.history_filters`)
MAX_HISTORY_FILTER = 100000


def _history(path: str, value: Any) -> list:
    """Lags in agent steps, each in [1, MAX_HISTORY_SAMPLES]."""
    return _increasing(path, value, MAX_HISTORY_SAMPLES, 16)


def _filters(path: str, value: Any) -> list:
    """Time constants in agent steps, each in [2, MAX_HISTORY_FILTER]."""
    out = _increasing(path, value, MAX_HISTORY_FILTER, 8)
    if any(k < 2 for k in out):
        fail(path, value, f"time constants in agent steps must each be in [2, {MAX_HISTORY_FILTER}]")
    return out


def _gauge(path: str, value: Any) -> Any:
    """``observation.preview_gauge``: 'exact', 'measured' or a mapping of `envs.gauge.GaugeSettings` fields."""
    try:
        gauge_settings(value)
    except ValueError as err:
        raise ValueError(f"env config {err}") from None
    return value


def _bool(path: str, value: Any) -> bool:
    if not isinstance(value, bool):
        fail(path, value, "must be true or false")
    return value


def _pair(path: str, value: Any, *, lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False,
          integer: bool = False) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        fail(path, value, "must be a [low, high] pair")
    a = number(f"{path}[0]", value[0], lo=lo, hi=hi, lo_open=lo_open, integer=integer)
    b = number(f"{path}[1]", value[1], lo=lo, hi=hi, lo_open=lo_open, integer=integer)
    if a > b:
        fail(path, value, "need low <= high")
    return a, b


def section(path: str, value: Any, fields: Mapping[str, Callable[[str, Any], Any]], *,
             required: tuple[str, ...] = ()) -> dict:
    if not isinstance(value, Mapping):
        fail(path, value, f"must be a mapping with keys {sorted(fields)}")
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
    return number(path, v, lo=0.0, lo_open=True)


def _nonneg(path, v):
    return number(path, v, lo=0.0)


#: the largest reward weight or penalty, and the range of a reward scale: an episode's return stays finite
#: (a step's cost is at most MAX_WEIGHT x (1e4 mm/s / 1e-6)^2 ~ 1e26, far from a float's 1.8e308)
MAX_WEIGHT, SCALE_RANGE = 1.0e6, (1.0e-6, 1.0e6)


def _weight(path, v):
    return number(path, v, lo=0.0, hi=MAX_WEIGHT)


def _scale(path, v):
    return number(path, v, lo=SCALE_RANGE[0], hi=SCALE_RANGE[1])


def _nonneg_pair(path, v):
    return _pair(path, v, lo=0.0)


def _count_pair(path, v):
    return _pair(path, v, lo=0, hi=1000, integer=True)


_DISTURBANCES = {
    "setpoint_steps": _optional(lambda p, v: section(p, v, {
        "count": _count_pair, "amplitude_m": lambda pp, vv: _pair(pp, vv, lo=0.0, hi=5e-3),
        "window_s": _nonneg_pair}, required=("count", "amplitude_m", "window_s"))),
    "force_steps": _optional(lambda p, v: section(p, v, {
        "count": _count_pair, "fraction": lambda pp, vv: _pair(pp, vv, lo=0.0, hi=1.0),
        "window_s": _nonneg_pair}, required=("count", "fraction", "window_s"))),
    "eccentricity": _optional(lambda p, v: section(p, v, {
        "amplitude_n": _nonneg_pair, "frequency_hz": lambda pp, vv: _pair(pp, vv, lo=0.0, hi=1000.0)},
        required=("amplitude_n", "frequency_hz"))),
    "sensor_noise": _optional(lambda p, v: section(p, v, {"x_m": _nonneg, "v_m_s": _nonneg, "a_m_s2": _nonneg})),
    "delay_steps": _optional(lambda p, v: number(p, v, lo=0, hi=100, integer=True)),
    "plant_change": _optional(lambda p, v: section(p, v, {
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
        fail(path, value, f"must be a non-empty list drawn from {list(_CHANGE_KINDS)}")


def _gain_bounds(path: str, value: Any) -> None:
    lo, hi = _pair(path, value)
    if not lo < hi:
        fail(path, value, "need low < high")


#: what a named gain set in an env config needs (the env layer takes numbers only)
_NAMED_HINT = ("the env layer takes gains as numbers; a named gain set is resolved before it (gym.make, make_vec_env "
               "and the CLI do that; in Python: millvib_env.catalog.named.resolve_named_gains)")


def _feedforward(path: str, value: Any) -> None:
    """A residual's fixed feedforward: observation channel name -> volts per unit of the channel (finite)."""
    if not isinstance(value, Mapping) or not value:
        fail(path, value, "a mapping of observation channel -> gain in V per unit of the channel (N or m), e.g. "
                           "{preview_force_8: -1.0e-5}")
    for k, g in value.items():
        if not isinstance(k, str):
            fail(f"{path} key", k, "an observation channel's name")
        if isinstance(g, bool) or not isinstance(g, (int, float)) or not math.isfinite(as_float(g)):
            fail(f"{path}.{k}", g, "a finite number (V per N or per m)")


def _residual_gains(path: str, value: Any) -> None:
    if isinstance(value, str):
        fail(path, value, _NAMED_HINT)
    if not isinstance(value, (list, tuple)) or len(value) not in (3, 4, 5):
        fail(path, value, "must be [KP, KI, KD], [KP, KI, KD, KPL] or [KP, KI, KD, KPL, KFF], each >= 0")
    for k, g in enumerate(value):
        number(f"{path}[{k}]", g, lo=0.0)


def _relative(path: str, value: Any) -> None:
    if value is None:
        return
    section(path, value, {"base": _base_gains, "decades": _decades}, required=("base",))


def _base_gains(path: str, value: Any) -> None:
    if isinstance(value, str):
        fail(path, value, _NAMED_HINT)
    if not isinstance(value, (list, tuple)) or not 3 <= len(value) <= 5:
        fail(path, value, "must be [KP, KI, KD] plus KPL and KFF where switched on, each >= 0 (> 0 where its "
                           "decades > 0)")
    for k, g in enumerate(value):
        number(f"{path}[{k}]", g, lo=0.0)


def _decades(path: str, value: Any) -> None:
    if isinstance(value, (list, tuple)):
        for k, d in enumerate(value):
            number(f"{path}[{k}]", d, lo=0.0, hi=6.0)
    else:
        number(path, value, lo=0.0, hi=6.0)


def checked_gains(gains: Any, where: str, hint: str = "") -> list[float]:
    """A fixed controller's gains, checked: 3-5 finite numbers >= 0 (KP, KI, KD[, KPL[, KFF]])."""
    if not isinstance(gains, list) or not 3 <= len(gains) <= 5:
        raise ValueError(f"{where} = {shown(gains)} is invalid: a list of 3-5 gains (KP, KI, KD[, KPL[, KFF]])"
                         + (f" ({hint})" if hint else ""))
    for k, g in enumerate(gains):
        if isinstance(g, bool) or not isinstance(g, (int, float)) or not math.isfinite(as_float(g)) or g < 0:
            raise ValueError(f"{where}[{k}] = {shown(g)} is invalid: a finite number >= 0")
    return [float(g) for g in gains]


SECTIONS: dict[str, Callable[[str, Any], Any]] = {
    "initial": lambda p, v: section(p, v, {
        "x0_m": lambda pp, vv: number(pp, vv, lo=-0.05, hi=0.05), "x0_jitter_m": lambda pp, vv: number(
            pp, vv, lo=0.0, hi=0.01), "settled": _bool,
        "setpoint_ramp_m_s": lambda pp, vv: number(pp, vv, lo=0.0, hi=10.0)}),
    "loop": _optional(lambda p, v: section(p, v, {
        "delay_samples": lambda pp, vv: number(pp, vv, lo=0, hi=1, integer=True),
        "derivative_filter_hz": _nonneg,
        "sensors": lambda pp, vv: section(pp, vv, {k: _nonneg for k in (
            "position_noise_m", "position_resolution_m", "pressure_noise_pa", "pressure_cutoff_hz",
            "force_noise_n", "force_cutoff_hz")})})),
    "disturbances": lambda p, v: section(p, v, _DISTURBANCES),
    "reward": lambda p, v: section(p, v, {
        "vibration_scale_mm_s": _scale, "tracking_scale_um": _scale, "vib_time_constant_s": _scale,
        "w_vibration": _weight, "w_tracking": _weight, "w_effort": _weight, "w_offset": _weight,
        "terminal_penalty": _weight, "terminal_per_step": _weight},
        required=("vibration_scale_mm_s", "tracking_scale_um", "vib_time_constant_s", "w_vibration",
                  "w_tracking", "w_effort", "terminal_penalty")),
    "actions": lambda p, v: section(p, v, {
        "kp": _gain_bounds, "ki": _gain_bounds, "kd": _gain_bounds, "kpl": _gain_bounds, "kff": _gain_bounds,
        "pressure_feedback": _bool, "force_feedforward": _bool, "relative": _relative,
        "u_range_v": _pos, "residual_range_v": _pos,
        "residual_gains": _residual_gains, "residual_feedforward": _feedforward,
        "scale": lambda pp, vv: vv in ("log", "linear") or fail(
            pp, vv, "'log' or 'linear'")},
        required=("kp", "ki", "kd", "kpl", "kff", "u_range_v", "residual_range_v", "residual_gains")),
    "envelope": lambda p, v: section(p, v, {
        "x_max_m": lambda pp, vv: number(pp, vv, lo=0.0, hi=0.1, lo_open=True),
        "p_min_pa": lambda pp, vv: number(pp, vv, hi=0.0), "p_max_factor": lambda pp, vv: number(
            pp, vv, lo=1.0, hi=9.0, lo_open=True)},
        required=("x_max_m", "p_min_pa", "p_max_factor")),
    "observation": lambda p, v: section(p, v, {"phase": _bool, "params": _bool, "force": _bool,
                                                "preview_samples": _preview, "history_samples": _history,
                                                "history_filters": _filters,
                                                "loop_sample": lambda pp, vv: vv in LOOP_SAMPLES or fail(
                                                    pp, vv, f"one of {list(LOOP_SAMPLES)}"),
                                                "preview_gauge": _gauge}),
}

TOP_KEYS = {"plant", "episode_s", "control_dt_s", "decision_dt_s", "sample_rate_hz", "randomize",
             *SECTIONS}
#: top-level keys a config may leave out (their absence is the v0 behaviour)
OPTIONAL_KEYS = {"loop"}
