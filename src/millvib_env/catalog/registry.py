"""The baselines by name: what each is and how it is built, in one table (`REGISTRY`).

A baseline is a `Baseline` entry: its description (the benchmark's and `millvib controllers`' text), its
builder (name, task, version, the task's env config and gain map -> a `Controller`), and whether it needs the
sampled loop (v1) or is a fixed gain set that a config may name. `catalog.factory.load_controller` builds any of
them, and agents by folder. A new fixed-gain baseline is one entry here (``Baseline.fixed(description)``) and its
entry in configs/control/[v1/]<task>.yaml (docs/maintainers.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from millvib_env._checks import shown
from millvib_env.control.adaptive import AdaptivePolicy, EstimatorSettings
from millvib_env.control.base import Controller
from millvib_env.control.lqr import LQRWeights
from millvib_env.control.mpc import MPCPolicy, MPCSettings
from millvib_env.control.policies import FixedGainPolicy, LQRPolicy, OraclePolicy
from millvib_env.control.preview import FF_CHANNELS, PreviewFeedforward
from millvib_env.catalog.tuned import control_config_path, control_entry, entry_gains, oracle_table
from millvib_env.envs.actions import GainMap
from millvib_env.envs.config import EnvConfig
from millvib_env.params import PAPER_GAINS
from millvib_env.tasks import Task

__all__ = ["Baseline", "REGISTRY", "BASELINES", "LOOP_ONLY", "REFERENCE", "ROOM_BOUNDS", "baseline_names",
           "fixed_gains", "tuned_gains", "paper_gains"]

#: a builder: (name, the task, environment version, the task's env config, its gain map) -> the controller
Builder = Callable[[str, Task, str, EnvConfig, GainMap], Controller]


#: a fixed-gain baseline's gains: (name, the task, environment version) -> (KP, KI, KD[, KPL[, KFF]], how they
#: were found)
GainsFn = Callable[[str, Task, str], "tuple[list[float], str]"]


@dataclass(frozen=True)
class Baseline:
    """One baseline: what it is, how it is built, and where it runs."""

    description: str
    build: Builder
    #: it needs the sampled loop (environment version v1)
    loop_only: bool = False
    #: the environment it acts in: "gain" (it sets the PID's gains) or "valve" (it commands the valve)
    env_mode: str = "gain"
    #: a fixed-gain baseline's gains (`Baseline.fixed`); env kwargs and hyperparameter files may then name it
    #: (`catalog.named`)
    gains: GainsFn | None = None
    #: it knows the disturbances' and the set-point's course ahead (a preview): the benchmark's room to learn
    #: keeps it apart from the bounds that know the present only
    previews: bool = False
    #: what it reads (`catalog.information`: atoms joined by "+")
    information: str = "loop"
    #: a deployable classical controller: the benchmark's group 'classical' and `millvib headroom`, and the best of
    #: them is named beside the room
    classical: bool = False
    #: the benchmark's default reference, the strongest deployable classical controller (exactly one: `REFERENCE`)
    reference: bool = False
    #: the benchmark pairs every controller with it too, beside the reference (`COMPARED_WITH`)
    compared_with: bool = False
    #: a command every loop sample from a QP: `--jobs auto` starts worker processes where it runs
    slow: bool = False
    #: a bound the benchmark's room to learn is measured with (it knows the plant: not deployable): what it stands
    #: for ("" where it is none), and its place among the bounds (`ROOM_BOUNDS`' order, the result's `room.bounds`)
    bound: str = ""
    bound_order: int = 0

    @classmethod
    def fixed(cls, description: str, gains: GainsFn | None = None, information: str = "loop", *,
              classical: bool = False, reference: bool = False, compared_with: bool = False) -> Baseline:
        """A fixed-gain baseline: its gains from `gains`, by default its entry in the task's control config
        (`tuned_gains`)."""
        return cls(description, fixed_gains, gains=gains or tuned_gains, information=information,
                   classical=classical, reference=reference, compared_with=compared_with)

    @property
    def named_gains(self) -> bool:
        """One fixed gain set, which env kwargs or a hyperparameter file may name."""
        return self.gains is not None


def tuned_gains(name: str, task: Task, version: str) -> tuple[list[float], str]:
    """Entry `name` of the task's control config in the version (`catalog.tuned`): its checked gains and ``how``."""
    entry = control_entry(task, name, version)
    return entry_gains(task, name, entry, version), entry.get("how", "")


def paper_gains(name: str, task: Task, version: str) -> tuple[list[float], str]:
    """The paper's PID, the same on every task."""
    return [float(g) for g in PAPER_GAINS.to_array()], REGISTRY[name].description


def fixed_gains(name: str, task: Task, version: str, cfg: EnvConfig, gain_map: GainMap) -> Controller:
    """A fixed-gain baseline (`Baseline.fixed`): its gains (`Baseline.gains`) as a `FixedGainPolicy`."""
    gains_fn = REGISTRY[name].gains
    if gains_fn is None:
        raise ValueError(f"baseline {shown(name)} has no fixed gains (a Baseline.fixed entry has)")
    gains, how = gains_fn(name, task, version)
    return FixedGainPolicy(name, gains, how)


def gain_oracle(name: str, task: Task, version: str, cfg: EnvConfig, gain_map: GainMap) -> Controller:
    """The true plant's gains from the entry's table (`control.base.GainTable`)."""
    return OraclePolicy(oracle_table(task, name, version), gain_map, name, task.config)


def lqr_oracle(name: str, task: Task, version: str, cfg: EnvConfig, gain_map: GainMap) -> Controller:

    entry = control_entry(task, name, version)
    return LQRPolicy(LQRWeights(**entry["weights"]), cfg.base_params, task, loop=cfg.loop)


def adaptive(name: str, task: Task, version: str, cfg: EnvConfig, gain_map: GainMap) -> Controller:
    entry = control_entry(task, name, version)
    return AdaptivePolicy(oracle_table(task, version=version), gain_map, EstimatorSettings(**entry["estimator"]),
                          cfg.base_params, sample_rate_hz=cfg.sample_rate_hz)


def preview_ff(name: str, task: Task, version: str, cfg: EnvConfig, gain_map: GainMap) -> Controller:
    """`pid-pf-preview` (`control.preview`): its 17 gains from its entry, on the task's pid-pf-robust."""
    if version == "v0":
        raise ValueError(f"{name} runs on the loop as commissioned: use environment version v1, not v0")
    entry = control_entry(task, name, version)
    gains = entry.get("gains") if isinstance(entry, dict) else None
    if not isinstance(gains, list) or len(gains) != len(FF_CHANNELS) or not all(
            isinstance(g, (int, float)) and not isinstance(g, bool) and math.isfinite(g) for g in gains):
        raise ValueError(f"{control_config_path(task, version)} {name}.gains = {shown(gains)} is invalid: "
                         f"{len(FF_CHANNELS)} finite numbers ({', '.join(FF_CHANNELS)})")
    base, _ = tuned_gains(REFERENCE, task, version)
    return PreviewFeedforward(name, gains, base, entry.get("how", ""))


def mpc(name: str, task: Task, version: str, cfg: EnvConfig, gain_map: GainMap) -> Controller:
    """`mpc-oracle` / `mpc-preview` with the task's settings (`control.mpc`); a preview where its entry says so
    (`Baseline.previews`)."""

    if version == "v0":
        raise ValueError(f"{name} runs on the loop as commissioned: use environment version v1, not v0")
    entry = control_entry(task, name, version)
    settings = entry.get("settings") if isinstance(entry, dict) else None
    if not isinstance(settings, dict):
        raise ValueError(f"{control_config_path(task, version)} {name}.settings = {shown(settings)} is invalid: "
                         "a mapping of MPCSettings fields")
    fields = [f for f in MPCSettings.__dataclass_fields__ if f != "preview"]
    unknown = sorted(str(k) for k in settings if k not in fields)
    if unknown:
        raise ValueError(f"{control_config_path(task, version)} {name}.settings has unknown keys {unknown}: "
                         f"allowed {fields}")
    return MPCPolicy(name, MPCSettings(**{**settings, "preview": REGISTRY[name].previews}), version)


#: every baseline by name, in the benchmark's order
REGISTRY: dict[str, Baseline] = {
    "pid-paper": Baseline.fixed("the paper's PID (KP = 1e5, KI = 1e-3, KD = 0)", paper_gains, classical=True),
    "pid-nominal": Baseline.fixed("tuned on the task's nominal plant only (Table 1 c1 and Ct), as a PID is "
                                  "commissioned", classical=True),
    "pid-robust": Baseline.fixed("one set of gains minimising the mean cost over the task's tuning plants",
                                 classical=True, compared_with=True),
    "pid-oracle": Baseline("knows the true c1 and Ct; gains tuned offline per plant (grid, interpolated); not "
                           "deployable", gain_oracle, information="loop+params", compared_with=True),
    "pid-adaptive": Baseline("estimates c1 and Ct online (RLS with forgetting) and takes the oracle's gains for the "
                             "estimate", adaptive, classical=True),
    "lqr-oracle": Baseline("knows the true c1 and Ct; LQR with integral action for PID + pressure feedback on the "
                           "linearised plant; not deployable", lqr_oracle, information="loop+params",
                           bound="a per-plant LQR with integral action", bound_order=1),
    "pid-pf-robust": Baseline.fixed("one fixed PID + pressure feedback (KP, KI, KD, KPL) for the task's whole range "
                                    "of c1 and Ct: the active damping a plant engineer commissions; the benchmark's "
                                    "reference", classical=True, reference=True),
    "pid-pf-ff": Baseline.fixed("pid-pf-robust plus a feedforward of the load cells' rolling-force deviation (KFF), "
                                "all five gains tuned together: the classical opponent of a controller that reads "
                                "the load cells", information="loop+force", classical=True),
    "pid-pf-oracle": Baseline("knows the true c1 and Ct; PID + pressure-feedback gains tuned offline per plant (grid, "
                              "interpolated): the bound for gain scheduling with pressure feedback on a fixed plant",
                              gain_oracle, information="loop+params",
                              bound="the per-plant re-tuned classical controller (PID + pressure feedback)"),
    "pid-pf-preview": Baseline("pid-pf-robust plus a linear feedforward of what the preview students read (the pass "
                               "schedule's and the entry gauge's force preview over 0.5-20 ms, the load cells): a "
                               "two-degree-of-freedom PID with a feedforward AGC, 17 gains tuned on the tuning plants "
                               "with the measured preview (control.preview); v1 only", preview_ff, loop_only=True,
                               env_mode="valve", information="loop+force+schedule+gauge", classical=True),
    "mpc-oracle": Baseline("knows the plant, its state and the disturbances now; model-predictive control of the "
                           "valve at the loop's rate within +-u_max (control.mpc): the bound for a controller of any "
                           "structure; not deployable; v1 only", mpc, loop_only=True, env_mode="valve",
                           information="loop+force+pump+params+state", slow=True,
                           bound="model-predictive control with the plant's state, within +-u_max", bound_order=2),
    "mpc-preview": Baseline("mpc-oracle that also knows the disturbances' and the set-point's course over its horizon "
                            "(an entry gauge's preview, made exact); not deployable; v1 only", mpc, loop_only=True,
                            env_mode="valve", previews=True, information="loop+force+schedule+gauge+pump+params+state",
                            slow=True, bound="mpc-oracle with the disturbances' course over its horizon (a preview)",
                            bound_order=3),
}
#: every baseline by name, with what it is
BASELINES: dict[str, str] = {name: b.description for name, b in REGISTRY.items()}
#: baselines that need the sampled loop (environment version v1)
LOOP_ONLY: tuple[str, ...] = tuple(name for name, b in REGISTRY.items() if b.loop_only)
#: the benchmark's default reference: the strongest deployable classical controller (`Baseline.reference`)
REFERENCE = next(name for name, b in REGISTRY.items() if b.reference)
#: the bounds the benchmark's room is measured with, each with what it stands for, in their order
#: (`Baseline.bound`): the first group measures the room without preview, mpc-preview with it
ROOM_BOUNDS: dict[str, str] = {name: b.bound for name, b in sorted(REGISTRY.items(),
                                                                  key=lambda item: item[1].bound_order) if b.bound}


def baseline_names(version: str | None = None) -> list[str]:
    """Every baseline's name; with `version`, those that run in that environment version."""
    return [n for n in REGISTRY if version != "v0" or n not in LOOP_ONLY]
