"""The benchmark's protocol: how many held-out plants, which preview, what a controller's episodes are summarised
into (`summarize`: the statistics of `evaluation.stats` per metric, the spread over training seeds, the actuator's
use) and the header every result starts from."""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from millvib_env.envs.batch import env_id_for
from millvib_env.envs.config import EnvConfig
from millvib_env.envs.scenarios import get_scenario, list_scenarios
from millvib_env.plant.model import rated_flow
from millvib_env.tasks import Task
from millvib_env.evaluation.evaluate import COST_SCALES
from millvib_env.evaluation.stats import METRICS, cvar, interval, iqm


#: how a benchmark gives a preview to the controllers that read one (`envs.gauge`), and its default
PREVIEW_GAUGES = ("measured", "exact", "failed")
#: each `PREVIEW_GAUGES` choice as the readers' ``observation.preview_gauge`` (`envs.gauge`): "failed" is the
#: measured preview whose gauge has lost its signal for the episode (every force change ahead missed)
PREVIEW_SETTINGS = {"measured": "measured", "exact": "exact", "failed": {"failed": True}}
DEFAULT_PREVIEW_GAUGE = "measured"
#: held-out plants per controller: the quick run (one seed per agent) and the full protocol (--all-seeds)
DEFAULT_EPISODES = 40
FULL_EPISODES = 200


def _by_seed(records: Sequence[Mapping[str, Any]]) -> list[list[Mapping[str, Any]]]:
    """Records split by the agent's training seed (`agent_seed`; one group for a fixed controller),
    each group in plant order."""
    groups: dict = {}
    for r in records:
        groups.setdefault(r.get("agent_seed"), []).append(r)
    return [groups[k] for k in sorted(groups, key=lambda k: (k is not None, k if k is not None else -1))]


def summarize(records: Sequence[Mapping[str, Any]]) -> dict:
    """One controller's summary over its episodes (an agent's: every training seed x the plants).
    The protocol's six metrics carry a 95 % interval (`millvib_env.evaluation.stats`)."""
    groups = _by_seed(records)
    sev = np.array([r["severity_mm_s"] for r in records], float)
    trk = np.array([r["tracking_rms_um"] for r in records], float)
    cost = np.array([r["cost"] for r in records], float)
    zones = {z: int(sum(r["iso_zone"] == z for r in records)) for z in "ABCD"}
    per = lambda key: [[r[key] for r in g] for g in groups]  # noqa: E731
    out = {"cost_mean": float(np.mean(cost)), "cost_iqm": iqm(cost), "cost_cvar20": cvar(cost),
           "cost_worst": float(np.max(cost)), "severity_mean": float(np.mean(sev)),
           "tracking_rms_um_mean": float(np.mean(trk)),
           "diverged_rate": float(np.mean([r["diverged"] for r in records])),
           "n_seeds": len(groups), "episodes": len(groups[0]) if groups else 0}
    for metric in ("mean", "iqm", "cvar20", "worst"):
        out[f"cost_{metric}_ci"] = interval(per("cost"), METRICS[metric])
    out["severity_mean_ci"] = interval(per("severity_mm_s"))
    out["tracking_rms_um_mean_ci"] = interval(per("tracking_rms_um"))
    out.update({"cost_median": float(np.median(cost)), "severity_median": float(np.median(sev)),
                "severity_p95": float(np.percentile(sev, 95)), "iso_zones": zones})
    if groups and groups[0][0].get("agent_seed") is not None:
        out["per_seed"] = [{"seed": g[0]["agent_seed"], "cost_mean": float(np.mean([r["cost"] for r in g])),
                            "cost_cvar20": cvar([r["cost"] for r in g]),
                            "severity_mean": float(np.mean([r["severity_mm_s"] for r in g]))} for g in groups]
    out.update(actuator_summary(records))
    for key in ("severity_start_mm_s", "severity_rest_mm_s", "pump_line_mm_s", "low_band_mm_s",
                "c1_log_error", "ct_log_error"):
        vals = [r[key] for r in records if key in r]
        if vals:
            out[key.replace("_mm_s", "") + "_mean"] = float(np.nanmean(vals)) if np.isfinite(vals).any() else math.nan
    return out


def _spread(values) -> dict:
    v = np.asarray(values, float)
    return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(np.max(v))}


def actuator_summary(records: Sequence[Mapping[str, Any]]) -> dict:
    """What a controller asked of its actuator, over its episodes: the valve command's largest magnitude per
    episode (median, p95, max; V) and its mean share of time at the amplifier's limit, the spool stroke used
    (m) and the peak flow against the rated flow (median, p95, max), the chamber pressure's range (Pa), and
    the number of episodes that diverged (scored at least `DIVERGED_COST`)."""
    return {"command": {"max_abs_v": _spread([r["command_max_abs_v"] for r in records]),
                        "share_at_limit": float(np.mean([r["command_at_limit_share"] for r in records]))},
            "spool_stroke_m": _spread([r["spool_stroke_m"] for r in records]),
            "peak_flow_ratio": _spread([r["peak_flow_ratio"] for r in records]),
            "pressure_pa": {"min": float(min(r["pl_min_pa"] for r in records)),
                            "max": float(max(r["pl_max_pa"] for r in records))},
            "n_diverged": int(sum(bool(r["diverged"]) for r in records))}


def loop_description(cfg: EnvConfig) -> dict:
    """The loop an environment config runs (the benchmark JSON's ``loop``): the controller's rate and delay,
    the amplifier's limit, the valve and the sensors; ``analog`` for the paper's continuous loop (v0)."""

    p = cfg.base_params
    valve = ({"natural_frequency_hz": p.valve_wn_hz, "damping": p.valve_zeta, "xv_max_m": p.xv_max,
              "m_per_v": p.xv_per_volt, "rated_flow_m3_s": rated_flow(p)} if not p.ideal_valve else
             {"ideal": True, "xv_max_m": p.xv_max, "m_per_v": p.xv_per_volt, "rated_flow_m3_s": rated_flow(p)})
    finite = lambda v: v if math.isfinite(v) else None  # noqa: E731 (JSON has no infinity: null = no limit)
    valve["xv_max_m"] = finite(valve["xv_max_m"])  # type: ignore[assignment]
    out = {"u_max_v": finite(p.u_max), "valve": valve}
    if cfg.loop is None:
        return {"kind": "analog", **out}
    return {"kind": "digital", **cfg.loop.describe(), **out}


def distinct_plant_scenarios() -> list[str]:
    """The named scenarios with distinct plants (a scenario's own fixed PID plays no part here)."""
    seen, names = set(), []
    for name in list_scenarios():
        sc = get_scenario(name)
        key = (tuple(sorted(sc.params.items())), sc.x0_m)
        if key not in seen:
            seen.add(key)
            names.append(name)
    return names


def _header(task: Task, version: str, reference: str, seed: int, episodes: int, all_seeds: bool) -> dict:
    """A benchmark's result before its runs: what it runs and on which loop."""
    return {"controllers": {}, "task": task.name, "reference": reference, "seed": seed, "episodes": episodes,
            "env_id": env_id_for("gain", version), "env_version": version,
            "loop": loop_description(task.configs[version]), "all_seeds": bool(all_seeds), "plants": [],
            "cost_scales": dict(COST_SCALES), "scenarios": {}, "records": {}}
