"""A benchmark's figures: the cost plane, the paired plane, the bars and one plant's traces."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from millvib_env._figures import log_span, panel_grid
from millvib_env._paths import save_figure
from millvib_env.catalog.factory import build_controller, load_controller
from millvib_env.envs.config import DEFAULT_VERSION
from millvib_env.tasks import Task
from millvib_env.evaluation.evaluate import trace_episode
from millvib_env.evaluation.benchmark.lineup import _preview_kwargs
from millvib_env.evaluation.benchmark.protocol import _by_seed


#: the failure scenario whose time traces the benchmark draws (fixed PIDs against agents)
TRACE_SCENARIO = "low-damping-high-leakage"


def _plot_traces(names: Sequence[str], path: Path, seed: int, *, task: Task, scenario: str | None = TRACE_SCENARIO,
                 version: str = DEFAULT_VERSION, preview: str = "exact", specs: Mapping | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")

    fig, grid, _ = panel_grid(4, 1, width=10, height=2.5, colorbar=False, margins=(0.85, 0.2, 0.55, 0.35),
                              sharex=True)
    axes = grid[:, 0]
    u_max = task.configs[version].base_params.u_max
    for k, name in enumerate(names):
        color = f"C{k % 10}"
        spec = (specs or {}).get(name)  # the benchmark's own lookup, where it made one
        ctrl = build_controller(spec) if spec is not None else load_controller(name, task, version=version)
        tr = trace_episode(ctrl, scenario=scenario, seed=seed, task=task,
                           env_kwargs=_preview_kwargs({name: ctrl}, preview).get(name))
        info = tr["info"]
        label = f"{name}: {info['severity']:.3g} mm/s, {info['tracking_rms_um']:.3g} um"
        axes[0].plot(tr["t"] * 1e3, tr["x"] * 1e6, lw=0.8, label=label, color=color)
        axes[1].plot(tr["t"] * 1e3, tr["v"] * 1e3, lw=0.6, color=color)
        axes[2].plot(tr["t"] * 1e3, tr["u"], lw=0.6, color=color)
        if len(tr["gains"]):
            steps = np.arange(len(tr["gains"])) * tr["step_s"] * 1e3
            kp = tr["gains"][:, 0]
            axes[3].step(steps, np.log10(np.where(kp > 0, kp, np.nan)), where="post", lw=1.0, color=color)
    if math.isfinite(u_max):  # the amplifier's rated range: no command leaves it
        for sign in (-1, 1):
            axes[2].axhline(sign * u_max, color="k", ls="--", lw=0.8)
    if scenario is not None:
        axes[0].set(ylabel="x (um)", title=f"Scenario '{scenario}' (c1 and Ct at their worst, 1 mm start): "
                                           "fixed PIDs against agents")
        axes[0].set_ylim(-600, 1050)
    else:
        plant = ", ".join(f"{k} = {v:.3g}" for k, v in tr["info"]["params"].items() if isinstance(v, (int, float)))
        title = f"Task '{task.name}', held-out plant {seed}: {plant}"
        axes[0].set(ylabel="x (um)", title=title if len(title) <= 120 else title[:title.rindex(", ", 0, 120)] + ", ...")
        axes[0].title.set_fontsize(9)
    axes[0].legend(fontsize=8)
    axes[1].set(ylabel="v (mm/s)")
    axes[2].set(ylabel="u (V)", title="valve command" + (f" (the amplifier's +-{u_max:g} V dashed)"
                                                          if math.isfinite(u_max) else ""))
    axes[3].set(ylabel="log10 KP", title="the PID's KP (gain schedules; gaps: KP <= 0)", xlabel="t (ms)")
    for ax in axes:
        ax.grid(alpha=0.3)
    return save_figure(fig, path, dpi=100)


def _plot_plane(result: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.colors import LogNorm

    names = list(result["records"])
    cols = min(3, len(names))
    rows = math.ceil(len(names) / cols)
    fig, axes, cax = panel_grid(rows, cols, width=4.8, height=4.2)
    all_sev = [r["severity_mm_s"] for recs in result["records"].values() for r in recs]
    norm = LogNorm(vmin=max(min(all_sev), 1e-2), vmax=max(all_sev))
    for ax, name in zip(axes.flat, names):
        recs = _by_seed(result["records"][name])[0]  # an agent's lowest seed
        sc = ax.scatter([r["Ct"] for r in recs], [r["c1"] for r in recs], c=[r["severity_mm_s"] for r in recs],
                        norm=norm, cmap="magma_r", s=40, edgecolors="k", linewidths=0.3)
        for r in recs:
            if r["diverged"]:
                ax.scatter(r["Ct"], r["c1"], marker="x", color="red", s=60)
        s = result["controllers"][name]
        log_span(ax, "x", [r["Ct"] for r in recs])
        log_span(ax, "y", [r["c1"] for r in recs])
        ax.set(xlabel="Ct (m^3/(s Pa))", ylabel="c1 (N s/m)",
               title=f"{name}\nmean {s['severity_mean']:.3g} mm/s, cost {s['cost_mean']:.3g}")
        ax.title.set_fontsize(9)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    fig.colorbar(sc, cax=cax, label="episode severity (mm/s)")
    return save_figure(fig, path, dpi=100)


def _plot_paired_plane(result: dict, path: Path) -> Path:
    """Per plant, each controller's cost relative to the reference's on that plant (mean over an
    agent's seeds), over the (Ct, c1) plane: where learning or adaptation helps and where not."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.colors import TwoSlopeNorm

    ref_name = result.get("reference", "pid-robust")
    ref = {r["seed"]: r for r in result["records"][ref_name]}
    names = [n for n in result["records"] if n != ref_name]
    cols = min(3, len(names))
    rows = math.ceil(len(names) / cols)
    fig, axes, cax = panel_grid(rows, cols, width=4.8, height=4.2, suptitle=0.45)
    diffs = {}
    for name in names:
        per_plant: dict = {}
        for r in result["records"][name]:
            per_plant.setdefault(r["seed"], []).append(r["cost"])
        diffs[name] = {k: 100 * (np.mean(v) / ref[k]["cost"] - 1) for k, v in per_plant.items()}
    lim = 40.0  # % either way; beyond it the colour saturates (pid-paper is several times dearer)
    norm = TwoSlopeNorm(vcenter=0.0, vmin=-lim, vmax=lim)
    for ax, name in zip(axes.flat, names):
        keys = list(diffs[name])
        sc = ax.scatter([ref[k]["Ct"] for k in keys], [ref[k]["c1"] for k in keys], c=[diffs[name][k] for k in keys],
                        norm=norm, cmap="RdBu_r", s=28, edgecolors="k", linewidths=0.2)
        pr = result["controllers"][name].get("paired", {}).get(ref_name, {})
        log_span(ax, "x", [ref[k]["Ct"] for k in keys])
        log_span(ax, "y", [ref[k]["c1"] for k in keys])
        ax.set(xlabel="Ct (m^3/(s Pa))", ylabel="c1 (N s/m)",
               title=f"{name} ({result['controllers'][name]['n_seeds']} seed(s))\nmean "
                     f"{100 * pr.get('cost_diff_rel', math.nan):+.1f} %, better on "
                     f"{100 * pr.get('p_improvement', math.nan):.0f} % of episodes")
        ax.title.set_fontsize(9)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    fig.colorbar(sc, cax=cax, label=f"cost vs {ref_name} on the plant (%, blue = cheaper)", extend="both")
    fig.suptitle(f"Task {result['task']}: paired cost difference to {ref_name} per held-out plant "
                 "(c1, Ct at the episode start)", fontsize=10)
    return save_figure(fig, path, dpi=100)


def _plot_bars(result: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")

    names = list(result["controllers"])
    fig, grid, _ = panel_grid(1, 3, width=13 / 3, height=4.6, colorbar=False, margins=(0.7, 0.2, 1.2, 0.35))
    for ax, key, label in zip(grid[0], ("severity_mean", "tracking_rms_um_mean", "cost_mean"),
                              ("mean severity (mm/s)", "mean tracking RMS (um)", "mean cost")):
        ax.bar(range(len(names)), [result["controllers"][n][key] for n in names], color="tab:blue")
        ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
        ax.set_title(label)
        ax.grid(alpha=0.3, axis="y")
    return save_figure(fig, path, dpi=100)
