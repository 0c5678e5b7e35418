"""Plant parameters and PID gains: validated, frozen, loadable from YAML presets.

`MillParams` holds the paper's Table 1 as defaults (SI units), named after the paper's symbols,
plus the pump pulsation and three modelling choices the paper leaves open (flow-root
regularisation, servo-amplifier saturation, pulsation harmonics). Every field documents its
meaning, unit and allowed range; constructing an instance with a value outside that range raises
`ValueError` naming the field, the value and the range.

The numeric fields are packed, in declaration order, into the float64 vector the compiled plant
model reads (`MillParams.to_array`, `PARAM_FIELDS`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from millvib_env._checks import as_float, shown, shown_path
from millvib_env._yaml import load_yaml

from millvib_env._paths import config_dir

__all__ = [
    "MillParams",
    "PIDGains",
    "PAPER_GAINS",
    "PARAM_FIELDS",
    "load_preset",
    "list_presets",
    "parse_overrides",
]


#: fields whose "none" is infinity: the paper's amplifier and valve have no limit
_MAY_BE_INF = ("u_max", "xv_max")


def _p(default: float, unit: str, doc: str, rule: str, studied: tuple[float, float] | None = None) -> Any:
    meta: dict[str, Any] = {"unit": unit, "doc": doc, "rule": rule}
    if studied is not None:
        meta["studied"] = studied
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class MillParams:
    """Parameters of the hydraulic screw-down system (paper Table 1, SI units).

    Equations (paper numbering): valve flow (1)-(3), chamber continuity (4), LuGre friction
    (5)-(7), piston force balance (8), PID (11). See `millvib_env.plant.model`.
    """

    Ap: float = _p(0.19635, "m^2", "rod-less chamber area (0.5 m bore)", "> 0")
    Ab: float = _p(0.030159, "m^2", "rod chamber effective area",
                   ">= 0 and < Ap (the rod side is an annulus of the bore)")
    mt: float = _p(1200.0, "kg", "equivalent mass of piston and load roll system", "> 0")
    c1: float = _p(2.25e6, "N s/m", "equivalent viscous damping (uncertain: temperature, wear)", ">= 0",
                   studied=(1.25e5, 2.25e6))
    k1: float = _p(2.5e9, "N/m", "load (mill stand) spring stiffness", ">= 0")
    FL: float = _p(2.0e6, "N", "external (rolling) force opposing extension", ">= 0")
    Ct: float = _p(5.0e-16, "m^3/(s Pa)", "internal leakage coefficient (uncertain: seal wear)", ">= 0",
                   studied=(5.0e-16, 5.0e-9))
    ps: float = _p(1.8e7, "Pa", "mean supply pressure", "> pt")
    pt: float = _p(0.0, "Pa", "return (tank) pressure", ">= 0")
    pb: float = _p(1.0e6, "Pa", "rod chamber back pressure (held constant)", ">= 0")
    beta_e: float = _p(7.0e8, "Pa", "effective bulk modulus of the oil", "> 0")
    rho: float = _p(850.0, "kg/m^3", "oil density", "> 0")
    Cd: float = _p(0.62, "-", "valve port flow (discharge) coefficient", "in (0, 1]")
    W: float = _p(0.025, "m", "valve area gradient (port width)", "> 0")
    Kp1: float = _p(0.0125, "A/V", "servo amplifier gain", "> 0")
    Ksv: float = _p(0.01, "m/A", "servo valve gain (spool stroke per current)", "> 0")
    L1: float = _p(0.15, "m", "initial piston stroke (sets the chamber volume Ap*(L1+x))", "> 0")
    L: float = _p(0.26, "m", "cylinder stroke; x must stay in [-L1, L-L1]", "> L1")
    sigma0: float = _p(4.4178e9, "N/m", "LuGre bristle stiffness", "> 0")
    sigma1: float = _p(1.0e5, "N s/m", "LuGre bristle micro-damping", ">= 0")
    sigma2: float = _p(1.0e5, "N s/m", "LuGre viscous friction", ">= 0")
    fc: float = _p(16000.0, "N", "Coulomb friction force", ">= 0")
    fs: float = _p(22000.0, "N", "maximum static (stiction) friction force", "> 0 and >= fc")
    vs: float = _p(0.1, "m/s", "Stribeck velocity", "> 0")
    pulse_amp: float = _p(
        0.12, "-", "pump pulsation: amplitude of the fundamental as a fraction of ps (paper: 12 %)",
        "in [0, 1)")
    pulse_freq: float = _p(
        115.5, "Hz", "pump pulsation frequency (990 rpm x 7 plungers / 60)", ">= 0")
    pulse_h2: float = _p(
        0.0, "-", "2nd-harmonic amplitude of the pulsation, relative to the fundamental",
        "finite, with pulse_amp*(1+|pulse_h2|+|pulse_h3|) < 1")
    pulse_h3: float = _p(
        0.0, "-", "3rd-harmonic amplitude of the pulsation, relative to the fundamental",
        "finite, with pulse_amp*(1+|pulse_h2|+|pulse_h3|) < 1")
    dp_reg: float = _p(
        1.0e5, "Pa", "orifice root regularisation: sqrt(|dp|) becomes dp/(dp^2+dp_reg^2)^(1/4) "
        "(Modelica regRoot); differs from sqrt by < 0.3 % for |dp| > 10*dp_reg", "> 0")
    u_max: float = _p(
        math.inf, "V", "servo-amplifier input saturation |u| <= u_max (paper: none, inf)",
        "> 0 (inf allowed)")
    valve_wn_hz: float = _p(
        0.0, "Hz", "servo-valve spool natural frequency (second-order lag from the command to the spool; "
        "0 = the paper's ideal proportional valve xv = Ksv Kp1 u)", ">= 0")
    valve_zeta: float = _p(0.7, "-", "servo-valve spool damping ratio (used when valve_wn_hz > 0)", "> 0")
    xv_max: float = _p(
        math.inf, "m", "spool stroke: the port opening is limited to |xv| <= xv_max (paper: none, inf)",
        "> 0 (inf allowed)")

    def __post_init__(self) -> None:
        for name, rule in _FIELD_RULES:
            value = getattr(self, name)
            given = value
            if type(value) is not float:  # a plain float is kept as it is; any other real becomes one
                if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                    raise ValueError(f"MillParams.{name} = {shown(value)} is invalid: must be a real number ({rule})")
                value = as_float(value)
                object.__setattr__(self, name, value)
            if not math.isfinite(value) and (math.isnan(value) or name not in _MAY_BE_INF or given != value):
                raise ValueError(f"MillParams.{name} = {shown(given)} is invalid: must be finite ({rule})")
        for name, ok in self._checks():
            if not ok:
                f = self.__dataclass_fields__[name]
                raise ValueError(
                    f"MillParams.{name} = {getattr(self, name)!r} [{f.metadata['unit']}] is invalid: "
                    f"allowed range is {f.metadata['rule']}")

    def _checks(self):
        h = abs(self.pulse_h2) + abs(self.pulse_h3)
        return [
            ("Ap", self.Ap > 0), ("Ab", 0 <= self.Ab < self.Ap), ("mt", self.mt > 0), ("c1", self.c1 >= 0),
            ("k1", self.k1 >= 0), ("FL", self.FL >= 0), ("Ct", self.Ct >= 0), ("pt", self.pt >= 0),
            ("ps", self.ps > self.pt), ("pb", self.pb >= 0), ("beta_e", self.beta_e > 0),
            ("rho", self.rho > 0), ("Cd", 0 < self.Cd <= 1), ("W", self.W > 0),
            ("Kp1", self.Kp1 > 0), ("Ksv", self.Ksv > 0), ("L1", self.L1 > 0), ("L", self.L > self.L1),
            ("sigma0", self.sigma0 > 0), ("sigma1", self.sigma1 >= 0), ("sigma2", self.sigma2 >= 0),
            ("fc", self.fc >= 0), ("fs", self.fs > 0 and self.fs >= self.fc), ("vs", self.vs > 0),
            ("pulse_amp", 0 <= self.pulse_amp < 1), ("pulse_freq", self.pulse_freq >= 0),
            ("pulse_h2", self.pulse_amp * (1 + h) < 1), ("pulse_h3", self.pulse_amp * (1 + h) < 1),
            ("dp_reg", self.dp_reg > 0), ("u_max", self.u_max > 0),
            ("valve_wn_hz", self.valve_wn_hz >= 0), ("valve_zeta", self.valve_zeta > 0), ("xv_max", self.xv_max > 0),
        ]

    @property
    def xv_per_volt(self) -> float:
        """Spool stroke per volt of command, Ksv Kp1 (m/V): 1.25e-4 for Table 1."""
        return self.Ksv * self.Kp1

    @property
    def ideal_valve(self) -> bool:
        """True for the paper's valve: the spool follows the command at once (valve_wn_hz = 0)."""
        return self.valve_wn_hz == 0.0

    # -- conversions -------------------------------------------------------------------------
    def replace(self, **changes: float) -> "MillParams":
        """A copy with some fields changed (validated); unknown names raise ValueError."""
        unknown = set(changes) - set(PARAM_FIELDS)
        if unknown:
            raise ValueError(f"unknown MillParams field(s) {sorted(unknown, key=repr)}; known: {list(PARAM_FIELDS)}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, float]:
        return {name: getattr(self, name) for name in PARAM_FIELDS}

    def to_array(self) -> np.ndarray:
        """Pack into the float64 vector the compiled model reads (order: `PARAM_FIELDS`)."""
        return np.array([getattr(self, name) for name in PARAM_FIELDS], dtype=np.float64)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "MillParams":
        unknown = set(data) - set(PARAM_FIELDS)
        if unknown:
            raise ValueError(f"unknown MillParams field(s) {sorted(unknown, key=repr)}; known: {list(PARAM_FIELDS)}")
        return cls(**{k: _as_float(k, v) for k, v in data.items()})

    @classmethod
    def from_yaml(cls, path: str | Path) -> "MillParams":
        data = load_yaml(path, "plant preset") or {}
        if not isinstance(data, dict) or not isinstance(data.get("params", {}), dict):
            raise ValueError(f"plant preset {shown_path(path)} must map parameter names to numbers (optionally under "
                             "'params:'); `millvib params` lists them")
        try:
            return cls.from_dict(data.get("params", data))
        except ValueError as err:
            raise ValueError(f"plant preset {shown_path(path)}: {err}") from None

    @classmethod
    def describe(cls) -> list[tuple[str, Any, str, str, str]]:
        """(name, default, unit, meaning, allowed range) for every field, for docs and the CLI."""
        return [(f.name, f.default, f.metadata["unit"], f.metadata["doc"], f.metadata["rule"])
                for f in dataclasses.fields(cls)]


PARAM_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(MillParams))
#: (name, allowed range) per field, in order: what `MillParams.__post_init__` checks
_FIELD_RULES: tuple[tuple[str, str], ...] = tuple((f.name, f.metadata["rule"]) for f in dataclasses.fields(MillParams))


def _as_float(name: str, value: Any) -> float:
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            raise ValueError(f"{name} = {shown(value)} is not a number") from None
    return value


@dataclass(frozen=True)
class PIDGains:
    """PID gains of the position loop, paper Eq. (11): u = KP e + KI int(e) dt + KD de/dt.

    Units: kp in V/m, ki in V/(m s), kd in V s/m (u is the servo-amplifier input in volts,
    e = xd - x in metres). All must be finite and >= 0. `kpl` (V/Pa, default 0: the paper's loop)
    adds pressure feedback, u -= KPL (pL - pL_ref), the textbook active damping of a hydraulic
    servo; `kff` (V/N, default 0) a feedforward of the load cells' force deviation, u += KFF dF;
    `to_array` gives (KP, KI, KD) only.
    """

    kp: float
    ki: float = 0.0
    kd: float = 0.0
    kpl: float = 0.0
    kff: float = 0.0

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd", "kpl", "kff"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise ValueError(f"PIDGains.{name} = {shown(value)} is invalid: must be a real number >= 0")
            given, value = value, as_float(value)
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"PIDGains.{name} = {shown(given)} is invalid: allowed range is [0, inf) (finite)")
            object.__setattr__(self, name, value)

    def to_array(self) -> np.ndarray:
        return np.array([self.kp, self.ki, self.kd], dtype=np.float64)

    def loop_gains(self) -> list[float]:
        """KP, KI, KD, then KPL where pressure feedback (or the feedforward) is on, then KFF where the
        feedforward is: the gains an environment's loop runs (``base_controller=``, `envs.actions.LoopController`)."""
        n = 5 if self.kff else 4 if self.kpl else 3
        return [self.kp, self.ki, self.kd, self.kpl, self.kff][:n]


#: The paper's nominal controller (given with its KP study): KP = 1e5, KI = 0.001, KD = 0.
PAPER_GAINS = PIDGains(kp=1.0e5, ki=1.0e-3, kd=0.0)


def studied_range(name: str) -> tuple[float, float]:
    """The range over which the paper studies an uncertain parameter (c1: 1.25e5-2.25e6 N s/m, Ct:
    5e-16-5e-9 m^3/(s Pa)): the one home of those numbers in the code (the tasks' draws are in
    configs/env/)."""
    import dataclasses

    for f in dataclasses.fields(MillParams):
        if f.name == name and "studied" in f.metadata:
            return tuple(f.metadata["studied"])
    raise ValueError(f"parameter {shown(name)} has no studied range; those with one: c1, Ct")


def list_presets() -> list[str]:
    """Names of the plant presets under configs/plant/."""
    return sorted(p.stem for p in (config_dir() / "plant").glob("*.yaml"))


def load_preset(name: str = "paper") -> MillParams:
    """Load `configs/plant/<name>.yaml` (or a path to a YAML file) as MillParams."""
    if not isinstance(name, (str, Path)) or not str(name):
        raise ValueError(f"preset = {shown(name)} is invalid: a preset name {list_presets()} or a YAML path")
    path = Path(name)
    if not path.suffix:
        path = config_dir() / "plant" / f"{name}.yaml"
        if not path.exists():
            raise ValueError(f"plant preset {shown(name)} not found (no file {shown_path(path)}); available: "
                             f"{list_presets()}")
    return MillParams.from_yaml(path)


def parse_overrides(items: list[str] | None) -> dict[str, float]:
    """Parse CLI overrides like ["c1=2.25e5", "Ct=5e-9"] into a dict of floats."""
    out: dict[str, float] = {}
    if items is not None and (isinstance(items, str) or not isinstance(items, (list, tuple))):
        raise ValueError(f"overrides = {shown(items)} is invalid: a list of NAME=VALUE strings")
    for item in items or []:
        if not isinstance(item, str) or "=" not in item:
            raise ValueError(f"override {shown(item)} must look like NAME=VALUE (e.g. c1=2.25e5)")
        key, _, value = item.partition("=")
        out[key.strip()] = _as_float(key.strip(), value.strip())
    return out
