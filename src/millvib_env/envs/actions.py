"""The gain/action mapping, in one place: gain-schedule actions in [-1, 1]^k <-> controller gains.

The gains are (KP, KI, KD), then KPL with ``actions.pressure_feedback: true`` and KFF with
``actions.force_feedforward: true``. Two mappings:

* **absolute** (the default): each gain is mapped onto its bounds (config section ``actions``), on
  a log scale, ``g = 10 ** (log10(lo) + (a + 1) / 2 * (log10(hi) - log10(lo)))``, or linearly with
  ``actions.scale: linear``, ``g = lo + (a + 1) / 2 * (hi - lo)`` (bounds may then be negative: the
  LQR reference's position gain can be, when its pressure feedback carries the position loop);
* **relative** (``actions.relative: {base: [...], decades: [...]}``): each entry is a bounded log
  offset around a base gain set, ``g = base * 10 ** (decades * a)``: the zero action is exactly
  the base controller (a fixed PID + pressure feedback, say), +-1 moves a gain by `decades` decades
  either way, and a gain with ``decades = 0`` stays pinned at its base value.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from millvib_env._checks import shown
from millvib_env.envs.config import EnvConfig

__all__ = ["GainMap", "GAIN_NAMES", "GAIN_UNITS", "WIDE_BOUNDS", "wide_actions", "fixed_actions", "LoopController",
           "base_controller_overrides"]

GAIN_NAMES = ("kp", "ki", "kd", "kpl", "kff")
GAIN_UNITS = {"kp": "V/m", "ki": "V/(m s)", "kd": "V s/m", "kpl": "V/Pa", "kff": "V/N"}
#: log bounds wide enough for the PID + pressure feedback (+ force feedforward) controllers' gains; KD
#: keeps the 300 V s/m limit every controller has (position-sensor noise, see configs/env/startup.yaml)
WIDE_BOUNDS = {"kp": (1e4, 1e7), "ki": (1e-3, 1e10), "kd": (1.0, 300.0), "kpl": (1e-8, 1e-2), "kff": (1e-7, 1e-1)}


def wide_actions(n_gains: int) -> dict:
    """The ``actions`` overrides of a gain-schedule env whose absolute action spans `WIDE_BOUNDS` with
    3 (PID), 4 (+ KPL) or 5 (+ KFF) gains."""
    if n_gains not in (3, 4, 5):
        raise ValueError(f"a gain set has 3 (PID), 4 (+ KPL) or 5 (+ KFF) entries, not {n_gains}")
    return {"pressure_feedback": n_gains >= 4, "force_feedforward": n_gains == 5,
            **{k: list(v) for k, v in WIDE_BOUNDS.items()}}


def fixed_actions(gains) -> dict:
    """The ``actions`` overrides in which every action is the fixed controller `gains` (3-5 entries),
    exactly: a relative map around them with zero range."""
    g = [float(v) for v in gains]
    return {"pressure_feedback": len(g) >= 4, "force_feedforward": len(g) == 5,
            "relative": {"base": g, "decades": 0.0}}


@runtime_checkable
class LoopController(Protocol):
    """A fixed controller that an environment's loop can run under the agent's action (``base_controller=``):
    its gains, KP, KI, KD, then KPL (pressure feedback) and KFF (force feedforward) where it has them. A
    `millvib_env.PIDGains` is one, and so is a fixed-gain baseline (``load_controller("pid-pf-robust")``)."""

    def loop_gains(self) -> Sequence[float]: ...


def base_controller_overrides(mode: str, residual: bool, controller: Any, overrides: Mapping) -> dict:
    """`overrides` (an environment's keyword arguments for its config) with `controller` (a `LoopController`, or
    None for none) as the fixed controller under the action: the residual valve action's
    (``actions.residual_gains``), or the gain action's base (``actions.relative.base``; the zero action is then
    exactly the controller, and +-1 moves each gain by the config's ``decades``, one by default)."""
    out = dict(overrides)
    if controller is None:
        return out
    if not isinstance(controller, LoopController):
        raise ValueError(f"base_controller = {shown(controller)} is invalid: a fixed controller with loop_gains() "
                         "(a PIDGains, or a fixed-gain baseline from load_controller, e.g. 'pid-pf-robust')")
    try:
        given: Any = controller.loop_gains()
        gains = [float(g) for g in given]
    except (TypeError, ValueError) as err:
        given, gains = f"an error ({type(err).__name__})", []
    if not 3 <= len(gains) <= 5 or not all(np.isfinite(gains)) or min(gains) < 0:
        raise ValueError(f"base_controller {shown(controller)} gives loop_gains() = {shown(given)}: 3 to 5 finite "
                         "gains >= 0 (KP, KI, KD[, KPL[, KFF]]) are needed")
    acts = out.get("actions")
    acts = dict(acts) if isinstance(acts, Mapping) else {}
    if mode == "valve":
        if not residual:
            raise ValueError("base_controller is given but residual = False: a controller runs under the valve "
                             "action in residual mode only (residual=True)")
        taken = "residual_gains"
        acts_new = {**acts, "residual_gains": gains}
    else:
        rel = acts.get("relative")
        rel = dict(rel) if isinstance(rel, Mapping) else {}
        taken = "relative" if "base" in rel else ""
        acts_new = {**acts, "pressure_feedback": len(gains) >= 4, "force_feedforward": len(gains) == 5,
                    "relative": {**rel, "base": gains}}
    if taken and taken in acts:
        raise ValueError(f"base_controller and actions.{taken} are both given: give one of them")
    out["actions"] = acts_new
    return out


def gain_names(pressure_feedback: bool, force_feedforward: bool = False) -> tuple[str, ...]:
    """The gains an action sets: KP, KI, KD, then KPL and KFF where the config switches them on."""
    return GAIN_NAMES[:3] + (("kpl",) if pressure_feedback else ()) + (("kff",) if force_feedforward else ())


@dataclass(frozen=True)
class GainMap:
    """Map between actions in [-1, 1]^dim and the gains `names`: onto bounds [lo, hi] (absolute) or
    as log offsets of +-`decades` around `base` (relative, when `base` is given)."""

    names: tuple[str, ...]
    lo: np.ndarray
    hi: np.ndarray
    log: bool = True
    base: np.ndarray | None = None
    decades: np.ndarray | None = None

    @classmethod
    def from_config(cls, config: EnvConfig, pressure_feedback: bool | None = None) -> "GainMap":
        acts = config.actions
        pf = config.pressure_feedback if pressure_feedback is None else pressure_feedback
        names = gain_names(pf, config.force_feedforward)
        lo = np.array([acts.bounds(k)[0] for k in names], float)
        hi = np.array([acts.bounds(k)[1] for k in names], float)
        rel = acts.relative
        if rel:
            base = np.asarray(rel.base, float)
            if base.shape != (len(names),):
                raise ValueError(f"env config actions.relative.base = {shown(rel.base)} is invalid: it needs "
                                 f"{len(names)} gains {list(names)} (pressure_feedback / force_feedforward set "
                                 "the entries)")
            try:
                decades = np.broadcast_to(np.asarray(rel.decades, float), base.shape).copy()
            except ValueError:
                raise ValueError(f"env config actions.relative.decades = {shown(rel.decades)} is invalid: one "
                                 f"number or {len(names)} of them, one per gain {list(names)}") from None
            if np.any((base <= 0) & (decades > 0)):
                raise ValueError(f"env config actions.relative.base = {shown(rel.base)} is invalid: a gain with a "
                                 "log offset (decades > 0) needs a base > 0")
            return cls(names, lo, hi, True, base, decades)
        return cls(names, lo, hi, config.log_scaled_gains)

    @property
    def relative(self) -> bool:
        return self.base is not None

    @property
    def dim(self) -> int:
        return len(self.names)

    def _relative_map(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(base, decades) of a relative map, None for an absolute one."""
        if self.base is None:
            return None
        assert self.decades is not None  # set with the base (from_config)
        return self.base, self.decades

    @property
    def log_lo(self) -> np.ndarray:
        return np.log10(self.lo)

    @property
    def log_hi(self) -> np.ndarray:
        return np.log10(self.hi)

    def gains(self, action: np.ndarray) -> np.ndarray:
        """Gains (..., dim) for actions (..., dim); actions outside [-1, 1] are clipped."""
        a = np.clip(action, -1.0, 1.0)
        rel = self._relative_map()
        if rel is not None:
            return rel[0] * 10.0 ** (rel[1] * a)
        frac = (a + 1.0) / 2.0
        if self.log:
            return 10.0 ** (self.log_lo + frac * (self.log_hi - self.log_lo))
        return self.lo + frac * (self.hi - self.lo)

    def action(self, gains) -> np.ndarray:
        """The action that maps to `gains` (..., dim, or 3: missing gains take their lowest bound, or
        their base in the relative map); clipped to [-1, 1]."""
        g = np.asarray(gains, dtype=np.float64)
        rel = self._relative_map()
        if g.shape[-1] < self.dim:
            fill = (self.lo if rel is None else rel[0])[g.shape[-1]:]
            g = np.concatenate([g, np.broadcast_to(fill, g.shape[:-1] + fill.shape)], axis=-1)
        g = g[..., :self.dim]
        if rel is not None:
            base, decades = rel
            with np.errstate(divide="ignore", invalid="ignore"):
                offset = np.log10(np.maximum(g, 1e-300) / base)
                a = np.where(decades > 0, offset / np.where(decades > 0, decades, 1.0), 0.0)
            return np.clip(a, -1.0, 1.0)
        if self.log:
            frac = (np.log10(np.maximum(g, 1e-300)) - self.log_lo) / (self.log_hi - self.log_lo)
        else:
            frac = (g - self.lo) / (self.hi - self.lo)
        return np.clip(2.0 * frac - 1.0, -1.0, 1.0)

    def start_gains(self, paper: np.ndarray) -> np.ndarray:
        """The gains an episode starts with: the base (relative map), else the paper's (KP, KI, KD)
        with KPL and KFF at their lowest bounds (or 0 where a linear bound allows it)."""
        rel = self._relative_map()
        if rel is not None:
            return rel[0].copy()
        rest = np.maximum(self.lo[3:], 0.0)
        return np.concatenate([np.asarray(paper, float)[:3], rest])

