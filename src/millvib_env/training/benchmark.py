"""`millvib benchmark`: every controller of a task on the same held-out plants (and, for `startup`,
on every named scenario).

Held-out plants: episode seeds ``seed, seed+1, ...`` inside the task's held-out range
(configs/tasks.yaml; a seed outside it is refused); each seed fixes the plant (c1, Ct), the
disturbances and the start, identically in both environment modes, so gain schedulers, valve
policies and fixed PIDs meet the same plants. Per controller: mean, median and 95th-percentile
severity (mm/s), its start (first 0.1 s) and the rest, the pump line's and the 10-100 Hz band's
levels, ISO zone counts, mean tracking RMS (um), diverged rate, mean episode cost
(severity / 4.5 mm/s + tracking RMS / 10 um) and its CVaR-20 (mean of the worst 20 % of episodes).
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from millvib_env._paths import save_figure, write_text_atomic
from millvib_env.control.policies import Controller, baseline_names, list_agents, load_controller
from millvib_env.envs.scenarios import get_scenario, list_scenarios
from millvib_env.tasks import get_task
from millvib_env.training.evaluate import COST_SCALES, run_episodes, trace_episode

__all__ = ["run_benchmark", "summarize", "format_table", "benchmark_from_cli", "DEFAULT_EPISODES", "cvar"]

DEFAULT_EPISODES = 40


def cvar(values: Sequence[float], worst_fraction: float = 0.2, axis: int = -1) -> float | np.ndarray:
    """Mean of the worst (largest) `worst_fraction` of the values (at least one), along `axis`."""
    v = -np.sort(-np.asarray(values, float), axis=axis)
    k = max(1, int(math.ceil(worst_fraction * v.shape[axis])))
    out = np.mean(np.take(v, np.arange(k), axis=axis), axis=axis)
    return float(out) if np.ndim(out) == 0 else out


#: bootstrap settings of every interval the benchmark reports (scipy.stats.bootstrap, BCa)
BOOTSTRAP = {"n_resamples": 2000, "confidence_level": 0.95, "method": "BCa"}
BOOTSTRAP_SEED = 12345


def interval(values: Sequence[float], statistic) -> list[float]:
    """95 % bootstrap interval of `statistic` over episodes (scipy.stats.bootstrap, BCa, seeded)."""
    from scipy import stats

    v = np.asarray(values, float)
    if v.size < 3 or not np.all(np.isfinite(v)) or np.ptp(v) == 0:
        value = float(statistic(v, axis=-1)) if v.size else math.nan
        return [value, value]
    res = stats.bootstrap((v,), statistic, rng=np.random.default_rng(BOOTSTRAP_SEED), **BOOTSTRAP)
    return [float(res.confidence_interval.low), float(res.confidence_interval.high)]


def paired_difference(costs: Sequence[float], reference: Sequence[float]) -> dict:
    """Relative difference of mean costs to a reference on the same episodes, with its paired 95 %
    bootstrap interval, and the probability of improvement (share of episodes cheaper than the
    reference; ties count half)."""
    from scipy import stats

    a, b = np.asarray(costs, float), np.asarray(reference, float)
    ratio = lambda x, y, axis=-1: np.mean(x, axis=axis) / np.mean(y, axis=axis) - 1.0  # noqa: E731
    diff = float(ratio(a, b))
    if a.size >= 3 and np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.ptp(a - b) > 0:
        res = stats.bootstrap((a, b), ratio, paired=True, vectorized=True,
                              rng=np.random.default_rng(BOOTSTRAP_SEED), **BOOTSTRAP)
        ci = [float(res.confidence_interval.low), float(res.confidence_interval.high)]
    else:
        ci = [diff, diff]
    p_improvement = float(np.mean((a < b) + 0.5 * (a == b)))
    return {"cost_diff_rel": diff, "ci": ci, "p_improvement": p_improvement}


def summarize(records: Sequence[dict]) -> dict:
    sev = np.array([r["severity_mm_s"] for r in records], float)
    trk = np.array([r["tracking_rms_um"] for r in records], float)
    cost = np.array([r["cost"] for r in records], float)
    zones = {z: int(sum(r["iso_zone"] == z for r in records)) for z in "ABCD"}
    out = {"severity_mean": float(np.mean(sev)), "severity_median": float(np.median(sev)),
           "severity_p95": float(np.percentile(sev, 95)), "tracking_rms_um_mean": float(np.mean(trk)),
           "diverged_rate": float(np.mean([r["diverged"] for r in records])), "cost_mean": float(np.mean(cost)),
           "cost_median": float(np.median(cost)), "cost_cvar20": cvar(cost), "cost_worst": float(np.max(cost)),
           "cost_mean_ci": interval(cost, np.mean), "cost_cvar20_ci": interval(cost, cvar),
           "iso_zones": zones, "episodes": len(records)}
    for key in ("severity_start_mm_s", "severity_rest_mm_s", "pump_line_mm_s", "low_band_mm_s",
                "c1_log_error", "ct_log_error"):
        vals = [r[key] for r in records if key in r]
        if vals:
            out[key.replace("_mm_s", "") + "_mean"] = float(np.nanmean(vals)) if np.isfinite(vals).any() else math.nan
    return out


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


def episode_records(name: str, task: str, seeds: list[int], env_id: str = "MillVib-GainSchedule-v0",
                    env_kwargs: dict | None = None) -> list[dict]:
    """One controller's episodes on `seeds` (a job of a distributed benchmark or sweep)."""
    ctrl = load_controller(name, task)
    ctrl_env = ctrl.env_id if getattr(ctrl, "card", None) else env_id
    return run_episodes(ctrl, seeds, env_id=ctrl_env, task=task, env_kwargs=env_kwargs)


#: episodes per job when a benchmark is spread over Ray
CHUNK = 50


def run_benchmark(controllers: Sequence[str] | None = None, *, task: str = "startup",
                  episodes: int = DEFAULT_EPISODES, seed: int | None = None, env_id: str = "MillVib-GainSchedule-v0",
                  scenarios: bool | None = None, progress: bool = True, ray: str | None = None) -> dict:
    """Evaluate `controllers` (default: every baseline and every agent trained on the task) on
    `episodes` held-out plants of `task` from episode seed `seed` (default: the first held-out seed).
    With `ray` (an address, or "" for a local cluster) controllers x chunks of CHUNK episodes run as
    Ray tasks; each episode depends only on its seed, so the numbers are the local run's."""
    t = get_task(task)
    if seed is None:
        seed = t.seeds["heldout"].start
    seeds = list(range(seed, seed + episodes))
    t.check_heldout(seeds)
    names = list(controllers) if controllers else baseline_names() + list_agents(t.name)
    loaded: dict[str, Controller] = {n: load_controller(n, t.name) for n in names}
    for name, ctrl in loaded.items():
        if getattr(ctrl, "card", None) is not None and ctrl.task != t.name:
            raise ValueError(f"agent {name!r} was trained on task {ctrl.task!r}, not {t.name!r}: benchmark it with "
                             f"--task {ctrl.task}")
    if scenarios is None:
        scenarios = t.name == "startup"  # the named scenarios are the paper's 1 mm starts
    result: dict = {"controllers": {}, "task": t.name, "seed": seed, "episodes": episodes, "env_id": env_id,
                    "cost_scales": dict(COST_SCALES), "scenarios": {}, "records": {}}
    start = time.time()
    distributed = None
    if ray is not None:
        from millvib_env.distributed import run_jobs

        jobs = [{"name": n, "task": t.name, "seeds": seeds[i:i + CHUNK], "env_id": env_id}
                for n in names for i in range(0, len(seeds), CHUNK)]
        parts = run_jobs(episode_records, jobs, ray=ray, progress=progress, desc=f"benchmark {t.name} (ray)")
        distributed = {n: [] for n in names}
        for job, part in zip(jobs, parts):
            distributed[job["name"]].extend(part)
    iterator = names
    if progress and distributed is None:
        from tqdm.auto import tqdm
        iterator = tqdm(names, desc=f"benchmark {t.name}", unit="controller")
    for name in iterator:
        ctrl = loaded[name]
        ctrl_env = ctrl.env_id if getattr(ctrl, "card", None) else env_id
        recs = distributed[name] if distributed is not None else run_episodes(ctrl, seeds, env_id=ctrl_env,
                                                                              task=t.name)
        summary = summarize(recs)
        summary["env_id"] = ctrl_env
        result["controllers"][name] = summary
        result["records"][name] = recs
        if scenarios:
            sc_recs = {}
            for sc in distinct_plant_scenarios():
                rec = run_episodes(ctrl, [seed], scenario=sc, env_id=ctrl_env, task=t.name)[0]
                sc_recs[sc] = {k: rec[k] for k in ("severity_mm_s", "tracking_rms_um", "iso_zone", "diverged",
                                                   "cost")}
            result["scenarios"][name] = sc_recs
    ref = result["records"].get("pid-robust")
    if ref is not None:
        stable = {r["seed"] for r in ref if not r["diverged"]}
        ref_cost = [r["cost"] for r in ref]
        for name, recs in result["records"].items():
            result["controllers"][name]["diverged_where_pid_robust_stable"] = int(
                sum(r["diverged"] and r["seed"] in stable for r in recs))
            if name != "pid-robust":
                result["controllers"][name]["paired_vs_pid_robust"] = paired_difference(
                    [r["cost"] for r in recs], ref_cost)
    result["wall_time_s"] = round(time.time() - start, 1)  # printed; not part of the result files
    return result


def format_table(result: dict) -> str:
    lines = [f"Task {result.get('task', 'startup')}, held-out plants: {result['episodes']} episodes, seeds "
             f"{result['seed']}-{result['seed'] + result['episodes'] - 1}; cost = severity / "
             f"{result['cost_scales']['severity_mm_s']} mm/s + tracking RMS / {result['cost_scales']['tracking_um']} um; "
             "CVaR-20 = mean of the worst 20 % of episodes; severity split at 0.1 s",
             "",
             "| controller | cost mean [95 % CI] | cost CVaR-20 [95 % CI] | vs pid-robust [95 % CI] | "
             "P(better) | severity mean (mm/s) | p95 | first 0.1 s | rest | pump line | "
             "10-100 Hz | tracking RMS (um) | zones A/B/C/D | diverged |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, s in result["controllers"].items():
        z = s["iso_zones"]
        pr = s.get("paired_vs_pid_robust")
        vs = (f"{100 * pr['cost_diff_rel']:+.1f} % [{100 * pr['ci'][0]:+.1f}, {100 * pr['ci'][1]:+.1f}]" if pr
              else "-")
        pb = f"{pr['p_improvement']:.2f}" if pr else "-"
        lines.append(f"| {name} | {s['cost_mean']:.3g} [{s['cost_mean_ci'][0]:.3g}, {s['cost_mean_ci'][1]:.3g}] | "
                     f"{s['cost_cvar20']:.3g} [{s['cost_cvar20_ci'][0]:.3g}, {s['cost_cvar20_ci'][1]:.3g}] | {vs} | {pb} | "
                     f"{s['severity_mean']:.3g} | "
                     f"{s['severity_p95']:.3g} | {s.get('severity_start_mean', math.nan):.3g} | "
                     f"{s.get('severity_rest_mean', math.nan):.3g} | {s.get('pump_line_mean', math.nan):.3g} | "
                     f"{s.get('low_band_mean', math.nan):.3g} | {s['tracking_rms_um_mean']:.3g} | "
                     f"{z['A']}/{z['B']}/{z['C']}/{z['D']} | {100 * s['diverged_rate']:.0f} % |")
    est = {n: s for n, s in result["controllers"].items() if "c1_log_error_mean" in s}
    for name, s in est.items():
        lines.append(f"\n{name}: mean estimation error over the episodes |log10(estimate / true)|: c1 "
                     f"{s['c1_log_error_mean']:.3f}, Ct {s['ct_log_error_mean']:.3f} (decades)")
    if result.get("scenarios"):
        names = list(result["scenarios"])
        scen = list(next(iter(result["scenarios"].values())))
        lines += ["", "Named scenarios with distinct plants, one episode each (severity mm/s / tracking RMS um):", "",
                  "| scenario | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for sc in scen:
            cells = []
            for n in names:
                r = result["scenarios"][n][sc]
                cells.append(("diverged " if r["diverged"] else "") + f"{r['severity_mm_s']:.3g} / "
                             f"{r['tracking_rms_um']:.3g}")
            lines.append(f"| {sc} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def public_json(result: dict) -> dict:
    """The summary without the per-episode records (those go to the CSV) and without timings, so the
    same inputs give the same bytes."""
    return {k: v for k, v in result.items() if k not in ("records", "wall_time_s")}


def _write_outputs(result: dict, out: Path) -> list[Path]:
    """Write the result folder as a whole: into a temporary sibling, then put in place
    (`atomic_folder`), so an interrupted or concurrent run never leaves a mix of two runs' files."""
    from millvib_env._paths import atomic_folder

    with atomic_folder(out) as tmp:
        files = _write_files(result, tmp)
    return [out / f.name for f in files]


def _write_files(result: dict, out: Path) -> list[Path]:
    files = []
    buf = io.StringIO()
    fields = ["controller", "seed", "c1", "Ct", "c1_end", "Ct_end", "severity_mm_s", "severity_start_mm_s",
              "severity_rest_mm_s", "pump_line_mm_s", "low_band_mm_s", "tracking_rms_um", "iso_zone", "diverged",
              "cost", "episode_return", "c1_log_error", "ct_log_error"]
    writer = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
    writer.writeheader()
    for name, recs in result["records"].items():
        for r in recs:
            writer.writerow({"controller": name, **r})
    files.append(write_text_atomic(out / "episodes.csv", buf.getvalue()))
    files.append(write_text_atomic(out / "benchmark.md", format_table(result) + "\n"))
    files.append(write_text_atomic(out / "benchmark.json", json.dumps(public_json(result), indent=2)))
    files.append(_plot_plane(result, out / "severity_plane.png"))
    files.append(_plot_bars(result, out / "cost_bars.png"))
    if result.get("task", "startup") == "startup":
        files.append(_plot_traces(list(result["controllers"]), out / f"traces_{TRACE_SCENARIO}.png", result["seed"]))
    else:
        files.append(_plot_traces(list(result["controllers"]), out / "traces.png", result["seed"],
                                  scenario=None, task=result["task"]))
    return files


#: the failure scenario whose time traces the benchmark draws (fixed PIDs against agents)
TRACE_SCENARIO = "low-damping-high-leakage"


def _plot_traces(names: Sequence[str], path: Path, seed: int, scenario: str | None = TRACE_SCENARIO,
                 task: str = "startup") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    for k, name in enumerate(names):
        color = f"C{k % 10}"
        tr = trace_episode(load_controller(name, task), scenario=scenario, seed=seed, task=task)
        info = tr["info"]
        label = f"{name}: {info['severity']:.3g} mm/s, {info['tracking_rms_um']:.3g} um"
        axes[0].plot(tr["t"] * 1e3, tr["x"] * 1e6, lw=0.8, label=label, color=color)
        axes[1].plot(tr["t"] * 1e3, tr["v"] * 1e3, lw=0.6, color=color)
        if len(tr["gains"]):
            steps = np.arange(len(tr["gains"])) * tr["step_s"] * 1e3
            kp = tr["gains"][:, 0]
            axes[2].step(steps, np.log10(np.where(kp > 0, kp, np.nan)), where="post", lw=1.0, color=color)
    if scenario is not None:
        axes[0].set(ylabel="x (um)", title=f"Scenario '{scenario}' (c1 and Ct at their worst, 1 mm start): "
                                           "fixed PIDs against agents")
        axes[0].set_ylim(-600, 1050)
    else:
        axes[0].set(ylabel="x (um)", title=f"Task '{task}', held-out plant {seed}: {tr['info']['params']}"[:110])
    axes[0].legend(fontsize=8)
    axes[1].set(ylabel="v (mm/s)")
    axes[2].set(ylabel="log10 KP (gain schedules; gaps: KP <= 0)", xlabel="t (ms)")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def _plot_plane(result: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    names = list(result["records"])
    cols = min(3, len(names))
    rows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.8 * cols, 4.2 * rows), squeeze=False, layout="constrained")
    all_sev = [r["severity_mm_s"] for recs in result["records"].values() for r in recs]
    norm = LogNorm(vmin=max(min(all_sev), 1e-2), vmax=max(all_sev))
    for ax, name in zip(axes.flat, names):
        recs = result["records"][name]
        sc = ax.scatter([r["Ct"] for r in recs], [r["c1"] for r in recs], c=[r["severity_mm_s"] for r in recs],
                        norm=norm, cmap="magma_r", s=40, edgecolors="k", linewidths=0.3)
        for r in recs:
            if r["diverged"]:
                ax.scatter(r["Ct"], r["c1"], marker="x", color="red", s=60)
        s = result["controllers"][name]
        ax.set(xscale="log", yscale="log", xlabel="Ct (m^3/(s Pa))", ylabel="c1 (N s/m)",
               title=f"{name}\nmean {s['severity_mean']:.3g} mm/s, cost {s['cost_mean']:.3g}")
        ax.title.set_fontsize(9)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    fig.colorbar(sc, ax=axes, label="episode severity (mm/s)", shrink=0.6)
    return save_figure(fig, path, dpi=100)


def _plot_bars(result: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result["controllers"])
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for ax, key, label in zip(axes, ("severity_mean", "tracking_rms_um_mean", "cost_mean"),
                              ("mean severity (mm/s)", "mean tracking RMS (um)", "mean cost")):
        ax.bar(range(len(names)), [result["controllers"][n][key] for n in names], color="tab:blue")
        ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
        ax.set_title(label)
        ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def benchmark_from_cli(args) -> int:
    from millvib_env._paths import check_output

    check_output(args.json, "--json")
    check_output(args.out, "--out", folder=True)
    if args.episodes < 1:
        raise ValueError(f"--episodes {args.episodes} is invalid: at least 1")
    result = run_benchmark(args.controllers, task=args.task, episodes=args.episodes, seed=args.seed, env_id=args.env,
                           scenarios=False if args.no_scenarios else None, progress=not args.quiet, ray=args.ray)
    print(format_table(result))
    print(f"\n({result['wall_time_s']} s)")
    if args.json:
        write_text_atomic(args.json, json.dumps(public_json(result), indent=2))
        print(f"wrote {args.json}")
    if args.out:
        files = _write_outputs(result, Path(args.out))
        print(f"wrote {len(files)} files to {args.out}")
    return 0
