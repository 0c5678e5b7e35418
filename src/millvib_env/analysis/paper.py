"""The paper's three one-at-a-time studies and their reproduction (`millvib reproduce`).

Each study varies one quantity from the nominal plant (Table 1, KP = 1e5, KI = 0.001, KD = 0),
starts from X00 = [1 mm, 0, 0] with xd = 0, and scores each case by its vibration severity:

* c1 = 2.25e6, 2.25e5, 1.25e5 N s/m (paper Figs. 4, 5)
* Ct = 5e-16, 5e-10, 5e-9 m^3/(s Pa) (Figs. 6, 7)
* KP = 1e5, 3.5e6, 3.9e6 V/m (Figs. 8, 9)

`reproduce` simulates them, measures severity, tracking error and the kind of motion
(`classify_motion`), draws the analogues of Figs. 4-9 plus two maps that show where in parameter
space the states the paper names (periodic, quasi-periodic) appear, and writes the numbers as CSV.
"""

from __future__ import annotations

import csv
import io
import json
import math
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from millvib_env._checks import integer
from millvib_env._figures import panel_grid
from millvib_env._paths import atomic_folder, save_figure, write_text_atomic
from millvib_env.analysis.linear import Friction, critical_kp, stability_maps
from millvib_env.analysis.studies import PAPER_STUDIES, PaperCase, PaperStudy
from millvib_env.distributed import expect_modules, run_jobs
from millvib_env.params import PAPER_GAINS, MillParams, PIDGains, studied_range
from millvib_env.plant.integrate import BatchResult, SimResult, simulate_batch
from millvib_env.severity import iso_zone

__all__ = ["PaperCase", "PaperStudy", "PAPER_STUDIES", "CaseResult", "run_studies", "reproduce"]


@dataclass(frozen=True)
class CaseResult:
    study: str
    label: str
    value: float
    severity_mm_s: float
    iso_zone: str
    motion: str
    amplitude_um: float
    frequency_hz: float
    tracking_rms_um: float
    diverged: bool

    def row(self) -> dict:
        return {"study": self.study, "case": self.label, "value": f"{self.value:.6g}",
                "severity_mm_s": f"{self.severity_mm_s:.4f}", "iso_zone": self.iso_zone,
                "motion": self.motion, "amplitude_um": f"{self.amplitude_um:.4g}",
                "frequency_hz": f"{self.frequency_hz:.1f}", "tracking_rms_um": f"{self.tracking_rms_um:.2f}",
                "diverged": self.diverged}


def run_studies(t_end: float = 1.0, method: str = "fast") -> tuple[list[CaseResult], dict[str, list[SimResult]]]:
    """Simulate the nine cases; returns per-case numbers and the runs, keyed by study."""
    # here: `reproduce` starts its motion map's plants before this import (scipy.signal, about half a second)
    from millvib_env.analysis.dynamics import classify_motion

    runs: dict[str, list[SimResult]] = {}
    results: list[CaseResult] = []
    for study in PAPER_STUDIES:
        batch = simulate_batch([c.params for c in study.cases], [c.gains for c in study.cases], t_end,
                               method=method)
        runs[study.key] = list(batch)
        for case, run in zip(study.cases, runs[study.key]):
            motion = classify_motion(run)
            sev = math.nan if run.diverged else run.severity()
            results.append(CaseResult(study.key, case.label, case.value, sev,
                                      "-" if run.diverged else iso_zone(sev), motion.label,
                                      motion.amplitude_m * 1e6, motion.frequency_hz,
                                      run.tracking_rms() * 1e6, run.diverged))
    return results, runs


def _plot_study(study: PaperStudy, runs: list[SimResult], out: Path, zoom_s: float = 0.06,
                tail_s: float = 0.05) -> Path:

    fig, grid, _ = panel_grid(1, 4, width=19 / 4, height=4.2, colorbar=False, suptitle=0.35,
                              margins=(1.0, 0.15, 0.55, 0.35))
    axes = grid[0]
    for case, run in zip(study.cases, runs):
        k = run.t <= zoom_s
        axes[0].plot(run.t[k] * 1e3, run.x[k] * 1e3, label=case.label)
        axes[1].plot(run.t * 1e3, run.x * 1e3, lw=0.8, label=case.label)
        axes[2].plot(run.x * 1e3, run.v * 1e3, lw=0.6, label=case.label)
        tail = run.t >= run.t[-1] - tail_s
        axes[3].plot((run.x[tail] - run.x[tail].mean()) * 1e6, run.v[tail] * 1e3, lw=0.8, label=case.label)
    axes[0].set(xlabel="t (ms)", ylabel="x (mm)", title=f"(a) displacement, first {zoom_s * 1e3:.0f} ms")
    axes[1].set(xlabel="t (ms)", ylabel="x (mm)", title="(b) displacement, whole run")
    axes[2].set(xlabel="x (mm)", ylabel="v (mm/s)", title="(c) phase portrait, whole run")
    axes[3].set(xlabel="x - mean (um)", ylabel="v (mm/s)", title=f"(d) phase portrait, last {tail_s * 1e3:.0f} ms")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"Study of {study.symbol} (paper {study.figures.split('-')[0].replace('Figs.', 'Fig.')}): "
                 "KP = %.3g, KI = %.3g, x0 = 1 mm" % (runs[0].gains.kp, runs[0].gains.ki))
    path = save_figure(fig, out / f"study_{study.key}_time_phase.png")
    return path


def _plot_severity(study: PaperStudy, results: list[CaseResult], out: Path) -> Path:

    fig, grid, _ = panel_grid(1, 1, width=5.5, height=4, colorbar=False, margins=(0.75, 0.15, 0.5, 0.35))
    ax = grid[0, 0]
    labels = [r.label for r in results]
    vals = [r.severity_mm_s for r in results]
    bars = ax.bar(range(len(vals)), vals, color="tab:blue")
    for bar, r in zip(bars, results):
        ax.annotate(f"{r.severity_mm_s:.3g}\n{r.motion}", (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                    ha="center", va="bottom", fontsize=8)
    ax.set_xticks(range(len(vals)), labels, fontsize=8)
    ax.set_ylabel("vibration severity (mm/s RMS, 10-1000 Hz)")
    ax.margins(y=0.15)  # room above the tallest bar for its label
    if max(vals) / max(min(vals), 1e-9) > 50:
        ax.set_yscale("log")
    ax.set_title(f"Severity vs {study.symbol} (paper Fig. {study.figures.split('-')[-1].strip()})")
    ax.grid(alpha=0.3, axis="y")
    path = save_figure(fig, out / f"study_{study.key}_severity.png")
    return path


#: the motion map's classes, in the order of its colours
_MOTION_KINDS = ("decay", "periodic", "quasi-periodic", "diverged")


def _motion_runs(t_end: float, n_c1: int, n_kp: int) -> tuple[np.ndarray, np.ndarray, BatchResult, np.ndarray]:
    """The motion map's plants over (c1, KP) from the paper's 1 mm start, Ct nominal, and their severities (NaN
    where a run diverged): compiled work and transforms that release the GIL, so `reproduce` runs it on a thread
    beside its other steps."""
    c1s = np.geomspace(*studied_range("c1"), n_c1)
    kps = np.geomspace(1e4, 1e7, n_kp)
    params = [MillParams(c1=c) for c in c1s for _ in kps]
    gains = [PIDGains(k, PAPER_GAINS.ki) for _ in c1s for k in kps]
    batch = simulate_batch(params, gains, t_end)
    severity = np.array([np.nan if run.diverged else run.severity() for run in batch])
    return c1s, kps, batch, severity


def _motion_map(out: Path, runs: tuple[np.ndarray, np.ndarray, BatchResult, np.ndarray], processes: int = 1,
                figure: bool = True) -> list[Path]:
    """Simulated kind of motion over (c1, KP) (`_motion_runs`): its CSV and, with `figure`, its picture with the
    linear critical KP."""
    from millvib_env.analysis.dynamics import classify_motion

    c1s, kps, batch, severity = runs
    n_kp = kps.size
    grid = np.zeros((c1s.size, n_kp), dtype=int)
    rows = []
    for idx, run in enumerate(batch):
        i, j = divmod(idx, n_kp)
        m = classify_motion(run)
        grid[i, j] = _MOTION_KINDS.index(m.kind)
        rows.append({"c1": f"{c1s[i]:.6g}", "KP": f"{kps[j]:.6g}", "motion": m.label,
                     "severity_mm_s": f"{severity[idx]:.4f}"})
    csv_path = _write_csv(out / "motion_map_c1_kp.csv", rows)
    return [_motion_figure(out, c1s, kps, grid, processes), csv_path] if figure else [csv_path]


def _motion_figure(out: Path, c1s: np.ndarray, kps: np.ndarray, grid: np.ndarray, processes: int) -> Path:
    from matplotlib.colors import ListedColormap

    fig, grid_ax, _ = panel_grid(1, 1, width=7, height=5, colorbar=False, margins=(0.95, 0.2, 0.55, 0.35))
    ax = grid_ax[0, 0]
    colors = ["#cfe8cf", "#f6c177", "#e06c75", "#555555"]
    cmap = ListedColormap(colors)
    ax.pcolormesh(kps, c1s, grid, cmap=cmap, vmin=-0.5, vmax=3.5, shading="nearest")
    ax.set(xscale="log", yscale="log", xlabel="KP (V/m)", ylabel="c1 (N s/m)",
           title="Motion after a 1 mm start (Ct = 5e-16, KI = 0.001)")
    for k, color in zip(_MOTION_KINDS, colors):
        ax.scatter([], [], marker="s", color=color, label=k)
    for study in PAPER_STUDIES:
        for case in study.cases:
            ax.scatter(case.gains.kp, case.params.c1, marker="x", color="k")
    ax.scatter([], [], marker="x", color="k", label="paper's cases")

    c1_fine = np.geomspace(c1s[0], c1s[-1], 40)
    frictions: tuple[tuple[Friction, str], ...] = (("stick", "-"), ("sliding", "--"))
    crit = run_jobs(critical_kp, [{"params": MillParams(c1=c), "ki": PAPER_GAINS.ki, "friction": friction}
                                  for friction, _ in frictions for c in c1_fine], processes=processes)  # one pool
    for n, (friction, style) in enumerate(frictions):
        ax.plot(crit[n * len(c1_fine):(n + 1) * len(c1_fine)], c1_fine, "k" + style, lw=1.2,
                label=f"linear KP_crit ({friction})")
    ax.set_xlim(kps[0] / 1.3, kps[-1] * 1.3)
    ax.legend(loc="lower left", fontsize=8)
    return save_figure(fig, out / "motion_map_c1_kp.png")


def _stability_figure(out: Path, n_c1: int, n_ct: int, progress: bool, processes: int = 1,
                      figure: bool = True) -> list[Path]:
    """Critical KP of the linearised loop against c1 (for three Ct) and against Ct (for three c1): its CSV and,
    with `figure`, its picture."""

    c1s = np.geomspace(*studied_range("c1"), n_c1)
    cts = np.geomspace(*studied_range("Ct"), n_ct)
    stick, slide = stability_maps(c1s, cts, frictions=("stick", "sliding"), progress=progress, processes=processes)
    rows = [{"c1": f"{c1s[i]:.6g}", "Ct": f"{cts[j]:.6g}", "kp_crit_stick": f"{stick[i, j]:.6g}",
             "kp_crit_sliding": f"{slide[i, j]:.6g}"} for i in range(n_c1) for j in range(n_ct)]
    csv_path = _write_csv(out / "stability_map.csv", rows)
    if not figure:
        return [csv_path]
    fig, grid, _ = panel_grid(1, 2, width=6, height=4.5, colorbar=False, margins=(0.85, 0.15, 0.55, 0.35))
    axes = grid[0]
    picks_ct = [0, n_ct // 2, n_ct - 1]
    picks_c1 = [0, n_c1 // 2, n_c1 - 1]
    for j, color in zip(picks_ct, ("C0", "C1", "C2")):
        axes[0].plot(c1s, stick[:, j], "-", color=color, label=f"stick, Ct = {cts[j]:.1e}")
        axes[0].plot(c1s, slide[:, j], "--", color=color, label=f"sliding, Ct = {cts[j]:.1e}")
    for i, color in zip(picks_c1, ("C0", "C1", "C2")):
        axes[1].plot(cts, stick[i, :], "-", color=color, label=f"stick, c1 = {c1s[i]:.2e}")
        axes[1].plot(cts, slide[i, :], "--", color=color, label=f"sliding, c1 = {c1s[i]:.2e}")
    for ax, xlabel in zip(axes, ("c1 (N s/m)", "Ct (m^3/(s Pa))")):
        for kp in (1e5, 3.5e6, 3.9e6):
            ax.axhline(kp, color="gray", lw=0.8, ls=":")
            ax.annotate(f"paper KP = {kp:.2g}", (0.01, kp),
                        xycoords=("axes fraction", "data"), fontsize=7, color="gray", va="bottom")
        ax.set(xscale="log", yscale="log", xlabel=xlabel, ylabel="critical KP (V/m)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    axes[0].set_title("Critical KP vs damping (KI = 0.001)")
    axes[1].set_title("Critical KP vs leakage (KI = 0.001)")
    return [save_figure(fig, out / "stability_map.png"), csv_path]


def _write_csv(path: Path, rows: list[dict]) -> Path:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    return write_text_atomic(path, buf.getvalue())


def format_table(results: list[CaseResult]) -> str:
    head = "| study | case | severity (mm/s) | ISO zone | motion (tail) | amplitude (um) | f (Hz) | tracking RMS (um) |"
    lines = [head, "|---|---|---|---|---|---|---|---|"]
    for r in results:
        # a decayed tail's residual is integration noise (< 1e-3 um): no amplitude or frequency to show
        amp, freq = ("-", "-") if r.motion == "decay" else (f"{r.amplitude_um:.3g}", f"{r.frequency_hz:.0f}")
        lines.append(f"| {r.study} | {r.label} | {r.severity_mm_s:.3f} | {r.iso_zone} | {r.motion} | "
                     f"{amp} | {freq} | {r.tracking_rms_um:.1f} |")
    return "\n".join(lines)


def claims(results: list[CaseResult]) -> list[dict]:
    """Per study: does the measured severity rise along the paper's direction, and which kinds."""
    out = []
    for study in PAPER_STUDIES:
        rs = [r for r in results if r.study == study.key]
        sev = [r.severity_mm_s for r in rs]
        rising = all(b > a for a, b in zip(sev, sev[1:]))
        out.append({"study": study.key, "direction_claim": study.claim_direction,
                    "direction_reproduced": bool(rising), "kind_claim": study.claim_kind,
                    "kinds_measured": " -> ".join(r.motion for r in rs)})
    return out


def reproduce(out_dir: str | Path, *, t_end: float = 1.0, method: str = "fast", maps: bool = True,
              map_resolution: int = 14, progress: bool = True, solver_study: bool = True,
              solver_study_only: bool = False, jobs: int = 1, figures: bool = True) -> dict:
    """Run the studies, write figures (PNG; none without `figures`) and numbers (CSV, JSON) into `out_dir`.

    `solver_study`: also integrate the nine cases with ode45's default tolerances and a ladder of
    tighter ones (`analysis.solver_study`); `solver_study_only`: only that (the other entries of an
    existing summary.json are kept). `jobs`: worker processes for the stability maps' cells and the solver
    study's runs (each independent: the same files as one process).
    """
    jobs = integer("jobs", jobs, lo=1, hi=1024)
    final = Path(out_dir)
    with atomic_folder(final, keep_existing=solver_study_only, command="reproduce") as out:
        summary = _reproduce_into(out, t_end, method, maps, map_resolution, progress, solver_study,
                                  solver_study_only, jobs, figures)
    summary["files"] = [str(final / Path(f).name) for f in summary["files"]]
    return summary


def _reproduce_into(out: Path, t_end, method, maps, map_resolution, progress, solver_study,
                    solver_study_only, jobs: int = 1, figures: bool = True) -> dict:
    modules = []  # the pools' modules: each pool's workers are forked with its module imported
    if jobs > 1 and maps and not solver_study_only:
        modules.append("millvib_env.analysis.linear")
    if jobs > 1 and (solver_study or solver_study_only):
        modules.append("millvib_env.analysis.solver_study")
    with expect_modules(*modules):
        return _reproduce_steps(out, t_end, method, maps, map_resolution, progress, solver_study,
                                solver_study_only, jobs, figures)


def _reproduce_steps(out: Path, t_end, method, maps, map_resolution, progress, solver_study,
                     solver_study_only, jobs: int, figures: bool) -> dict:
    # the motion map's plants (most of the run's compiled work) go on a thread from the start, beside the rest
    background = ThreadPoolExecutor(max_workers=1, thread_name_prefix="motion-map")
    try:
        motion = (background.submit(_motion_runs, t_end, map_resolution, map_resolution + 4)
                  if maps and not solver_study_only else None)
        result = _reproduce_files(out, t_end, method, maps, map_resolution, progress, solver_study,
                                  solver_study_only, jobs, figures, motion)
    except BaseException:
        # a run ended by Ctrl-C or an error does not wait for the map's compiled plants (one call that cannot be
        # stopped: a minute on a busy machine while numba compiles it); the command's launcher leaves at once
        background.shutdown(wait=False, cancel_futures=True)
        raise
    background.shutdown(wait=True)
    return result


def _reproduce_files(out: Path, t_end, method, maps, map_resolution, progress, solver_study,
                     solver_study_only, jobs: int, figures: bool, motion: Future | None) -> dict:
    """The steps in the order that leaves the motion map's plants the most time on their thread; the files listed
    in the order of the paper (cases, motion map, stability map, solver study, summary)."""
    case_files: list[Path] = []
    stability_files: list[Path] = []
    solver_files: list[Path] = []
    summary: dict = {}
    if solver_study_only:
        old = out / "summary.json"
        summary = json.loads(old.read_text()) if old.is_file() else {}
    else:
        results, runs = run_studies(t_end, method)
        case_files.append(_write_csv(out / "paper_cases.csv", [r.row() for r in results]))
        for study in PAPER_STUDIES if figures else ():
            case_files.append(_plot_study(study, runs[study.key], out))
            case_files.append(_plot_severity(study, [r for r in results if r.study == study.key], out))
        if maps:
            stability_files = _stability_figure(out, map_resolution, map_resolution, progress, jobs, figures)
        summary = {"t_end_s": t_end, "method": method, "claims": claims(results),
                   "cases": [r.row() for r in results]}
    if solver_study or solver_study_only:
        from millvib_env.analysis.solver_study import format_solver_table, plot_solver_study, run_solver_study, verdicts

        rows, solver_runs = run_solver_study(t_end, progress=progress, processes=jobs)
        solver_files.append(_write_csv(out / "solver_study.csv", [r.row() for r in rows]))
        if figures:
            solver_files.extend(plot_solver_study(rows, solver_runs, out))
        summary["solver_study"] = {"rows": [r.row() for r in rows], "verdicts": verdicts(rows)}
    motion_files = [] if motion is None else _motion_map(out, motion.result(), jobs, figures)
    files = case_files + motion_files + stability_files + solver_files
    public = {k: v for k, v in summary.items() if k not in ("table", "files", "solver_table")}
    files.append(write_text_atomic(out / "summary.json", json.dumps(public, indent=2)))
    if not solver_study_only:
        summary["table"] = format_table(results)
    if "solver_study" in summary and (solver_study or solver_study_only):
        summary["solver_table"] = format_solver_table(rows)
    summary["files"] = [str(f) for f in files]
    return summary
