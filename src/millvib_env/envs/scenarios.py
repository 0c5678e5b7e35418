"""Named scenarios: the paper's fixed-PID failure cases, replayable in the environments.

``env.reset(options={"scenario": NAME})`` pins the scenario's plant parameters and starts from its
initial deviation; a "quiet" scenario also switches the episode's set-point and force steps off,
as in the paper (only the 1 mm start and the pump pulsation). Each scenario names the fixed PID it
was built to expose (the paper's KP = 1e5, its highest KP = 3.9e6, or a PID commissioned at
KP = 3.5e6 on the nominal plant) and the outcome tests/test_scenarios.py asserts for that PID,
measured by simulating the scenario's 0.5 s episode.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from millvib_env._checks import shown
from millvib_env.params import PAPER_GAINS, MillParams, PIDGains
from millvib_env.plant.integrate import simulate

__all__ = ["Scenario", "SCENARIOS", "get_scenario", "list_scenarios", "measure_scenario", "format_scenarios",
           "COMMISSIONED_GAINS"]

#: a PID commissioned on the nominal plant at the paper's high gain (its KP study's 3.5e6)
COMMISSIONED_GAINS = PIDGains(3.5e6, 1e-3, 0.0)
#: the paper's highest gain (its KP study)


HIGH_GAINS = PIDGains(3.9e6, 1e-3, 0.0)


@dataclass(frozen=True)
class Scenario:
    """A named plant and start, the fixed PID it exposes, and the outcome asserted for that PID.

    expect_motion: "decay" (the 1 mm start dies out) or "sustained" (vibration that never dies);
    expect_zone: the ISO zone the episode's severity reaches at least; worse_than: a scenario whose
    severity under its own PID this one's exceeds.
    """

    name: str
    description: str
    params: dict = field(default_factory=dict)
    gains: PIDGains = PAPER_GAINS
    pid: str = "paper"
    expect_motion: str = "decay"
    expect_zone: str = "A"
    worse_than: str | None = None
    x0_m: float = 1.0e-3
    quiet: bool = True

    def plant(self, base: MillParams | None = None) -> MillParams:
        return (base or MillParams()).replace(**self.params)

    @property
    def expected(self) -> str:
        text = f"{self.pid} PID: {'the start decays' if self.expect_motion == 'decay' else 'sustained vibration'}"
        text += f", zone {self.expect_zone} or worse"
        return text + (f", more severe than '{self.worse_than}'" if self.worse_than else "")


SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("nominal", "Table 1 plant (c1 = 2.25e6, Ct = 5e-16) under the paper's PID: the reference case.",
             {}, expect_motion="decay", expect_zone="B"),
    Scenario("low-damping", "Damping fallen to the paper's lowest c1 = 1.25e5 N s/m (hot oil), paper PID.",
             {"c1": 1.25e5}, expect_motion="decay", expect_zone="C", worse_than="nominal"),
    Scenario("high-leakage", "Worn seals, the paper's highest leakage Ct = 5e-9 m^3/(s Pa), paper PID: the "
             "valve stays open, so the pump ripple drives the cylinder, and the loop sags.",
             {"Ct": 5.0e-9}, expect_motion="sustained", expect_zone="D", worse_than="low-damping"),
    Scenario("low-damping-high-leakage", "Both at once (c1 = 1.25e5, Ct = 5e-9), paper PID.",
             {"c1": 1.25e5, "Ct": 5.0e-9}, expect_motion="sustained", expect_zone="D", worse_than="high-leakage"),
    Scenario("high-gain", "Nominal plant under the paper's highest gain KP = 3.9e6: fast correction, large "
             "transient.", {}, HIGH_GAINS, "highest-gain", expect_motion="decay", expect_zone="D",
             worse_than="nominal"),
    Scenario("commissioned-low-damping", "A PID commissioned at KP = 3.5e6 on the nominal plant after the "
             "damping falls to c1 = 2.25e5: a self-excited limit cycle.", {"c1": 2.25e5}, COMMISSIONED_GAINS,
             "commissioned", expect_motion="sustained", expect_zone="D", worse_than="high-gain"),
    Scenario("commissioned-worst", "The commissioned KP = 3.5e6 PID in the worst corner, c1 = 1.25e5 and "
             "Ct = 5e-9.", {"c1": 1.25e5, "Ct": 5.0e-9}, COMMISSIONED_GAINS, "commissioned",
             expect_motion="sustained", expect_zone="D", worse_than="high-gain"),
)}


def list_scenarios() -> list[str]:
    return list(SCENARIOS)


def get_scenario(name: str) -> Scenario:
    if not isinstance(name, str) or name not in SCENARIOS:
        raise ValueError(f"scenario {shown(name)} unknown; available: {list_scenarios()}")
    return SCENARIOS[name]


def measure_scenario(name: str, t_end: float = 0.5, gains: PIDGains | None = None) -> dict:
    """Simulate a scenario under its fixed PID (or `gains`): severity, zone, motion, tracking."""
    from millvib_env.analysis.dynamics import classify_motion

    sc = get_scenario(name)
    run = simulate(sc.plant(), gains or sc.gains, t_end, x0=sc.x0_m)
    motion = classify_motion(run)
    out = {"scenario": name, "pid": sc.pid, "kp": (gains or sc.gains).kp, "diverged": run.diverged,
           "motion": motion.label, "sustained": not motion.settled}
    if not run.diverged:
        sev = run.severity()
        out.update({"severity_mm_s": sev, "iso_zone": run.iso_zone(), "tracking_rms_um": run.tracking_rms() * 1e6,
                    "final_offset_um": (run.xd[-1] - run.x[-1]) * 1e6})
    return out


def format_scenarios(measure: bool = True) -> str:
    lines = ["| scenario | plant | fixed PID | severity (mm/s) | zone | motion | tracking RMS (um) | description |",
             "|---|---|---|---|---|---|---|---|"]
    for sc in SCENARIOS.values():
        plant = ", ".join(f"{k} = {v:.3g}" for k, v in sc.params.items()) or "Table 1"
        if measure:
            m = measure_scenario(sc.name)
            cells = (f"{m['severity_mm_s']:.3g} | {m['iso_zone']} | {m['motion']} | {m['tracking_rms_um']:.1f}"
                     if not m["diverged"] else "diverged | - | - | -")
        else:
            cells = "- | - | - | -"
        lines.append(f"| {sc.name} | {plant} | {sc.pid} (KP = {sc.gains.kp:.3g}) | {cells} | {sc.description} |")
    return "\n".join(lines)
