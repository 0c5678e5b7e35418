"""The preview as a mill measures it: the rolling force's course ahead as an entry-thickness gauge upstream of the
stand tells it, through a force model and a transport delay (`observation.preview_gauge`).

An exact preview (the default, ``preview_gauge: exact``) carries the plant's own force course: every force step at
its true time and size, and the roll eccentricity's phase. A gauge does not:

* **timing.** The gauge reads the strip `transport_s` before it reaches the roll bite; the controller times the
  arrival from the measured strip speed, whose relative error (forward slip is not measured) is drawn once per
  episode, N(0, `speed_error`). Every force change arrives ``transport_s x error`` later than the preview says
  (rounded to the loop's sample): 1 ms RMS at the defaults (0.1 s of transport, 1 % speed error);
* **size.** The force a thickness change brings is predicted by a force model; the strip's hardness is not
  measured, so each change's size carries its own relative error, N(0, `force_model_error`) (10 % RMS);
* **noise.** The gauge's noise through the force model: white, `noise_n` N RMS on every loop sample's predicted
  force (10 kN at the defaults: 2 um of entry thickness at 5 MN/mm of plasticity);
* **eccentricity.** The rolls' eccentricity is the stand's own and never passes the gauge: not in the preview
  (``eccentricity: true`` puts the exact one back);
* **a failed gauge** (``failed: true``, off in ``measured``): the gauge's signal is lost for the whole episode
  and the preview holds the force it read at the episode's start: every change ahead is missed, no noise. What a
  controller that reads the preview does when its gauge fails and nobody switches its feedforward off.

The pass schedule's set-point course stays exact: it is the controller's own.

The draws come from the episode's fifth `SeedSequence` child (`envs.episode.draw_episode`), so the plant, the
disturbances and the sensors' noise are the same numbers with either preview.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

import numpy as np

from millvib_env._checks import shown

__all__ = ["GaugeSettings", "MEASURED", "gauge_settings", "gauge_force"]


@dataclass(frozen=True)
class GaugeSettings:
    """The measured preview's errors (module docstring); the defaults are ``preview_gauge: measured``."""

    transport_s: float = 0.1          # gauge to roll bite at the strip's speed (s)
    speed_error: float = 0.01         # the strip speed's relative error, RMS, drawn per episode
    force_model_error: float = 0.1    # each force change's relative error, RMS (hardness not measured)
    noise_n: float = 1.0e4            # the gauge's noise as force, RMS per loop sample (N)
    eccentricity: bool = False        # the rolls' eccentricity in the preview (a gauge never sees it)
    failed: bool = False              # the gauge's signal lost: the preview holds the episode's first reading

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("eccentricity", "failed"):
                if not isinstance(v, (bool, np.bool_)):
                    raise ValueError(f"observation.preview_gauge.{f.name} = {shown(v)} is invalid: true or false")
                continue
            limit = {"transport_s": 10.0, "speed_error": 0.5, "force_model_error": 1.0, "noise_n": 1.0e6}[f.name]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not 0 <= v <= limit:
                raise ValueError(f"observation.preview_gauge.{f.name} = {shown(v)} is invalid: a number in "
                                 f"[0, {limit:g}]")


#: the measured preview's defaults
MEASURED = GaugeSettings()


def gauge_settings(value: Any) -> GaugeSettings | None:
    """``observation.preview_gauge`` as settings: "exact" (or None) -> None; "measured" -> the defaults; a mapping ->
    the defaults with its fields replaced."""
    if value is None or value == "exact":
        return None
    if isinstance(value, GaugeSettings):
        return value
    if value == "measured":
        return MEASURED
    if isinstance(value, Mapping):
        known = [f.name for f in fields(GaugeSettings)]
        unknown = sorted(str(k) for k in value if k not in known)
        if unknown:
            raise ValueError(f"observation.preview_gauge has unknown keys {unknown}: allowed {known}")
        return GaugeSettings(**dict(value))
    raise ValueError(f"observation.preview_gauge = {shown(value)} is invalid: 'exact', 'measured' or a mapping of "
                     f"{[f.name for f in fields(GaugeSettings)]}")


def gauge_force(dfl: np.ndarray, rng: np.random.Generator, dt_s: float, g: GaugeSettings) -> np.ndarray:
    """The force course (N, one value per loop sample, as `dfl`) a gauge with errors `g` predicts for the
    episode whose true force-step course is `dfl`: its changes shifted by the timing error and scaled by the model
    error, plus noise. Draws, in order: the speed error, one model error per change, the noise. A failed gauge
    (`GaugeSettings.failed`) predicts the first value throughout and draws nothing."""
    dfl = np.asarray(dfl, float)
    n = len(dfl)
    if g.failed:
        return np.full(n, dfl[0])
    shift = int(round(g.transport_s * g.speed_error * rng.standard_normal() / dt_s))
    jumps = np.diff(dfl)
    at = np.flatnonzero(jumps)
    sizes = jumps[at] * (1.0 + g.force_model_error * rng.standard_normal(len(at)))
    course = np.zeros(n)
    np.add.at(course, np.clip(at + 1 + shift, 0, n - 1), sizes)
    out = dfl[0] + np.cumsum(course)
    return out + g.noise_n * rng.standard_normal(n)
