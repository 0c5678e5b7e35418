"""The sampled loop's settings: the config's ``loop`` section, typed, with its defaults in one place.

A mill's gap controller is a digital program: every ``1 / rate_hz`` seconds it samples the position
transducer, the pressure transducer and the load cells, computes the valve command, and holds it
until the next sample (zero-order hold). The command leaves the controller one sample after its
inputs were read when ``delay_samples = 1`` (the computation delay of a controller that writes its
output at the next interrupt). The servo amplifier's rated input, +-u_max, is the plant's
(`MillParams.u_max`); the controller saturates at the same limit and stops integrating there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

__all__ = ["LoopSettings", "SensorSettings", "LS_FIELDS", "NLS"]


@dataclass(frozen=True)
class SensorSettings:
    """The transducers the controller (and the agent) reads.

    * position: a magnetostrictive transducer, Gaussian noise ``position_noise_m`` RMS, quantised to
      ``position_resolution_m`` (0: not quantised);
    * pressure: the chamber's pressure transducer, a first-order low-pass at ``pressure_cutoff_hz``
      (0: none), then Gaussian noise ``pressure_noise_pa`` RMS (0.05 MPa: the 0.1-0.25 %-of-full-scale
      class of a 25-40 MPa transducer);
    * force: the load cells' rolling force deviation FL(t) - FL, a first-order low-pass at
      ``force_cutoff_hz`` (0: none), then Gaussian noise ``force_noise_n`` RMS.
    """

    position_noise_m: float = 5.0e-7
    position_resolution_m: float = 1.0e-7
    pressure_noise_pa: float = 5.0e4
    pressure_cutoff_hz: float = 1000.0
    force_noise_n: float = 5.0e3
    force_cutoff_hz: float = 500.0


@dataclass(frozen=True)
class LoopSettings:
    """The digital loop: rate, computation delay, the derivative's filter, the sensors."""

    rate_hz: float = 2000.0
    delay_samples: int = 1
    derivative_filter_hz: float = 500.0
    sensors: SensorSettings = SensorSettings()

    @property
    def dt_s(self) -> float:
        return 1.0 / self.rate_hz

    @classmethod
    def from_config(cls, section: Mapping[str, Any], rate_hz: float) -> "LoopSettings":
        """From the config's (validated) ``loop`` section; the rate is the config's control rate."""
        sensors = SensorSettings(**dict(section.get("sensors") or {}))
        rest = {k: v for k, v in section.items() if k != "sensors"}
        return cls(rate_hz=float(rate_hz), sensors=sensors, **rest)

    def vector(self) -> np.ndarray:
        """The float64 vector the compiled loop reads (`LS_FIELDS` order): the filters' discrete
        coefficients at the loop's rate, the noise levels and the resolution."""
        dt = self.dt_s
        s = self.sensors

        def smoothing(cutoff_hz: float) -> float:  # a first-order low-pass sampled exactly (ZOH)
            return 1.0 if cutoff_hz <= 0 else 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * dt)

        values = {"dt": dt, "delay": float(self.delay_samples), "a_deriv": smoothing(self.derivative_filter_hz),
                  "x_noise": s.position_noise_m, "x_res": s.position_resolution_m,
                  "p_noise": s.pressure_noise_pa, "a_p": smoothing(s.pressure_cutoff_hz),
                  "f_noise": s.force_noise_n, "a_f": smoothing(s.force_cutoff_hz)}
        return np.array([values[k] for k in LS_FIELDS])

    def describe(self) -> dict:
        """The settings as a JSON-able dict (the benchmark's ``loop``)."""
        return {"rate_hz": self.rate_hz, "delay_samples": self.delay_samples,
                "derivative_filter_hz": self.derivative_filter_hz,
                "sensors": dict(vars(self.sensors))}


#: the loop vector's entries, in order
LS_FIELDS = ("dt", "delay", "a_deriv", "x_noise", "x_res", "p_noise", "a_p", "f_noise", "a_f")
NLS = len(LS_FIELDS)
